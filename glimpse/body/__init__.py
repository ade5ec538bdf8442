"""The body layer: SMPL-format models (official SMPL or the free body), keypoints,
skinning of Gaussians, and motion input.

    from glimpse.body import BodyModel, keypoint_map, bake_skin_weight_grid, load_motion

Names are imported on first use, so that light modules (``glimpse.body.config``,
read by every ``make`` through ``glimpse run``) do not pay for importing torch.
"""

from importlib import import_module

_EXPORTS = {
    "config": ("BodyConfig", "SkinningConfig", "check_scene_body_model", "resolve_model_path"),
    "keypoints": ("LAYOUTS", "KeypointMap", "keypoint_map"),
    "model": ("BodyModel", "BodyOutput"),
    "model_file": ("JOINT_NAMES", "NUM_JOINTS", "SMPL_PARENTS", "BodyModelData", "load_body_model_file"),
    "motion": ("BUILTIN_MOTIONS", "BodySequence", "builtin_motion", "load_motion", "resample"),
    "skinning": ("SkinWeightGrid", "bake_skin_weight_grid", "blend_transforms", "canonical_body_pose",
                 "canonical_to_posed", "deform_gaussians", "idw_skin_weights"),
}
_MODULE_OF = {name: module for module, names in _EXPORTS.items() for name in names}
__all__ = sorted(_MODULE_OF)


def __getattr__(name: str):
    if name not in _MODULE_OF:
        raise AttributeError(f"module 'glimpse.body' has no attribute {name!r}")
    return getattr(import_module(f"glimpse.body.{_MODULE_OF[name]}"), name)
