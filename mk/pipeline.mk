# The stage DAG. Called by the top-level Makefile after `glimpse prepare` has
# validated the scene and written RUN/.params/<stage>.json and RUN/.inputs/<stage>.json
# (rewritten only when they change). Targets are the stages' manifests.
# Mirrors glimpse/pipeline/stages.py (tests/test_pipeline_dag.py checks).
STAGES := 01_sfm 02_smpl_fit 03_masks 04_bg_pretrain 05_textual_inversion 06_joint_opt 07_eval

DEPS_01_sfm :=
DEPS_02_smpl_fit := 01_sfm
DEPS_03_masks := 01_sfm 02_smpl_fit
DEPS_04_bg_pretrain := 01_sfm 02_smpl_fit 03_masks
DEPS_05_textual_inversion := 01_sfm 02_smpl_fit 03_masks
DEPS_06_joint_opt := 01_sfm 02_smpl_fit 03_masks 04_bg_pretrain 05_textual_inversion
DEPS_07_eval := 01_sfm 02_smpl_fit 03_masks 04_bg_pretrain 06_joint_opt

# Where the stage scripts live (tests point it at their own).
STAGES_DIR ?= stages

.PHONY: all print-dag
all: $(RUN)/07_eval/manifest.json

define stage_rule
$(RUN)/$(1)/manifest.json: $(RUN)/.params/$(1).json $(RUN)/.inputs/$(1).json $(foreach d,$(DEPS_$(1)),$(RUN)/$(d)/manifest.json)
	$(PY) $(STAGES_DIR)/$(1)/run.py --scene "$(SCENE)" --out "$(OUT)"
endef
$(foreach s,$(STAGES),$(eval $(call stage_rule,$(s))))

print-dag:
	@$(foreach s,$(STAGES),echo "$(s): $(DEPS_$(s))";)
