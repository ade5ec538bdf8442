"""Stage 02's logic: one mode per person, ``provided`` > ``keypoints3d`` > ``keypoints2d``
unless forced; body parameters for the frames the pipeline has (stage 01's cameras); the
residuals against whatever keypoints the scene gives.

Built so far: ``provided``. The fitting modes arrive with the rest of issue #7; a person
that needs one stops the stage with a clear message (no output is faked).
"""

from __future__ import annotations

from dataclasses import dataclass

from glimpse.body.model import BodyModel
from glimpse.body.params import BodyParams, read_scene_smpl
from glimpse.cameras.model import PinholeCamera
from glimpse.errors import GlimpseError, NotImplementedStageError
from glimpse.fit.config import FitConfig
from glimpse.fit.residuals import body_keypoints, residuals_2d, residuals_3d, summary
from glimpse.io.images import frame_name
from glimpse.scene import HumanInputs, Scene, read_keypoints2d, read_keypoints3d

FIT_MODES_PENDING = "issue #7 (fitting to 3D and 2D keypoints)"


@dataclass
class PersonFit:
    pid: str
    mode: str
    params: BodyParams
    report: dict


def choose_mode(person: HumanInputs, config: FitConfig) -> str:
    available = [m for m, path in (("provided", person.smpl), ("keypoints3d", person.keypoints3d),
                                   ("keypoints2d", person.keypoints2d)) if path is not None]
    if config.mode != "auto":
        if config.mode not in available:
            raise GlimpseError(f"person {person.pid}: 02_smpl_fit.mode={config.mode} needs "
                               f"humans/{person.pid}/{_file_of(config.mode)}; the scene has: {', '.join(available) or 'none'}")
        return config.mode
    if not available:
        raise GlimpseError(f"person {person.pid}: no smpl.npz, keypoints3d.npz or keypoints2d.npz to fit a body to "
                           f"(masks alone do not give a body)")
    return available[0]


def _file_of(mode: str) -> str:
    return {"provided": "smpl.npz", "keypoints3d": "keypoints3d.npz", "keypoints2d": "keypoints2d.npz"}[mode]


def fit_person(scene: Scene, person: HumanInputs, model: BodyModel, cameras: dict[int, PinholeCamera],
               config: FitConfig) -> PersonFit:
    """Body parameters of one person over the frames that have a camera, with a residual report."""
    mode = choose_mode(person, config)
    if mode != "provided":
        raise NotImplementedStageError(
            f"person {person.pid}: stage 02 mode {mode} is not implemented yet (it arrives with {FIT_MODES_PENDING}); "
            f"give humans/{person.pid}/smpl.npz to use the provided parameters")
    params = read_scene_smpl(person.smpl, scene.body_model).select(sorted(cameras))
    if len(params.frame_ids) == 0:
        raise GlimpseError(f"person {person.pid}: smpl.npz has no frame among the {len(cameras)} frames with a camera")
    return PersonFit(person.pid, mode, params, _report(person, model, params, cameras, config, mode))


def _report(person: HumanInputs, model: BodyModel, params: BodyParams, cameras: dict[int, PinholeCamera],
            config: FitConfig, mode: str) -> dict:
    report: dict = {"format": "glimpse-fit-report/1", "person": person.pid, "mode": mode,
                    "frames": len(params.frame_ids), "units_3d": "world units (metres in a metric frame)"}
    per_frame: dict[int, dict] = {int(f): {} for f in params.frame_ids}
    for layout_source, key in ((person.keypoints3d, "keypoints3d"), (person.keypoints2d, "keypoints2d")):
        if layout_source is None:
            continue
        observed = read_keypoints3d(layout_source) if key == "keypoints3d" else read_keypoints2d(layout_source)
        predicted = dict(zip(params.frame_ids.tolist(), body_keypoints(model, params, observed.layout)))
        if key == "keypoints3d":
            values = residuals_3d(predicted, observed.frame_ids, observed.joints, config.keypoint_min_confidence)
        else:
            values = residuals_2d(predicted, observed.frame_ids, observed.keypoints, cameras,
                                  config.keypoint_min_confidence)
        report[f"{key}_residual"] = summary(values)
        for fid, value in values.items():
            per_frame.setdefault(fid, {})[key] = value
    report["per_frame"] = {frame_name(f): v for f, v in sorted(per_frame.items())}
    return report

