# The stage rules. Called by the top-level Makefile after `glimpse prepare` has validated the scene and
# written RUN/.dag.mk (the DAG, from glimpse/pipeline/stages.py), RUN/.params/<stage>.json and
# RUN/.inputs/<stage>.json, each rewritten only when it changes. Targets are the stages' manifests.
include $(RUN)/.dag.mk

# Where the stage scripts live (tests point it at their own).
STAGES_DIR ?= stages

.PHONY: all
all: $(foreach s,$(STAGES),$(RUN)/$(s)/manifest.json)

define stage_rule
$(RUN)/$(1)/manifest.json: $(RUN)/.params/$(1).json $(RUN)/.inputs/$(1).json $(foreach d,$(DEPS_$(1)),$(RUN)/$(d)/manifest.json)
	$(PY) $(STAGES_DIR)/$(1)/run.py --scene "$(SCENE)" --out "$(OUT)"
endef
$(foreach s,$(STAGES),$(eval $(call stage_rule,$(s))))
