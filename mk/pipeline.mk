# The stage rules, run by `glimpse run` from inside the run folder OUT/<scene>/ (make -C), after it has taken
# the run's lock, validated the scene and written .dag.mk (the DAG, from glimpse/pipeline/stages.py),
# .params/<stage>.json and .inputs/<stage>.json, each rewritten only when it changes. Targets are the stages'
# manifests, relative to the run folder. The scene, the output root, the Python and the stage scripts reach the
# recipes only as environment variables (GLIMPSE_SCENE, GLIMPSE_OUT, GLIMPSE_PYTHON, GLIMPSE_STAGES_DIR), always
# quoted: a path may hold spaces, quotes, backticks or dollars.
include .dag.mk

.PHONY: all
all: $(foreach s,$(STAGES),$(s)/manifest.json)

define stage_rule
$(1)/manifest.json: .params/$(1).json .inputs/$(1).json $(foreach d,$(DEPS_$(1)),$(d)/manifest.json)
	@"$$$$GLIMPSE_PYTHON" "$$$$GLIMPSE_STAGES_DIR/$(1)/run.py" --scene "$$$$GLIMPSE_SCENE" --out "$$$$GLIMPSE_OUT"
endef
$(foreach s,$(STAGES),$(eval $(call stage_rule,$(s))))
