"""Body parameters of one person over frames: the smplx-style record every stage exchanges
(CONTRACTS.md), and its file, ``body.npz`` (format ``glimpse-body-params/1``).

Posed vertices are ``scale * LBS(betas, global_orient, body_pose) + transl``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glimpse.body.motion import interpolate_pose_sequence
from glimpse.errors import GlimpseError

BODY_PARAMS_FORMAT = "glimpse-body-params/1"
BODY_MODEL_KINDS = ("free", "smpl")


@dataclass(frozen=True)
class BodyParams:
    """frame_ids [T] int; betas [10]; global_orient [T, 3] and body_pose [T, 69] axis-angle (radians);
    transl [T, 3] (world units); scale: world units per metre of body (1 in a metric frame);
    body_model: "free" | "smpl"; interpolated [T] bool: frames filled in rather than observed."""

    frame_ids: np.ndarray
    betas: np.ndarray
    global_orient: np.ndarray
    body_pose: np.ndarray
    transl: np.ndarray
    scale: float
    body_model: str
    interpolated: np.ndarray

    def __post_init__(self) -> None:
        T = len(self.frame_ids)
        shapes = {"betas": (self.betas.shape, (10,)), "global_orient": (self.global_orient.shape, (T, 3)),
                  "body_pose": (self.body_pose.shape, (T, 69)), "transl": (self.transl.shape, (T, 3)),
                  "interpolated": (self.interpolated.shape, (T,))}
        for name, (found, expected) in shapes.items():
            if found != expected:
                raise ValueError(f"BodyParams.{name}: expected shape {expected}, found {found}")
        if self.body_model not in BODY_MODEL_KINDS:
            raise ValueError(f"BodyParams.body_model must be one of {BODY_MODEL_KINDS}, found {self.body_model!r}")

    def select(self, frame_ids: list[int] | np.ndarray) -> "BodyParams":
        """The same person restricted to ``frame_ids`` (those it has; order kept)."""
        keep = np.isin(self.frame_ids, np.asarray(frame_ids))
        return BodyParams(self.frame_ids[keep], self.betas, self.global_orient[keep], self.body_pose[keep],
                          self.transl[keep], self.scale, self.body_model, self.interpolated[keep])


    def with_frames_between(self, frame_ids: list[int] | np.ndarray) -> "BodyParams":
        """The same person also at those of ``frame_ids`` that lie strictly between two of their frames and are
        not theirs (held-out frames of the input video): every joint rotation slerped and the translation lerped
        between the neighbouring frames (glimpse.body.motion.interpolate_pose_sequence), marked interpolated.
        Their own rows are kept exactly; ids outside their span are left out."""
        own = self.frame_ids.astype(np.int64)
        wanted = np.unique(np.asarray(frame_ids, np.int64))
        new = wanted[(wanted > own.min()) & (wanted < own.max()) & ~np.isin(wanted, own)] if len(own) else wanted[:0]
        if len(new) == 0:
            return self
        order = np.argsort(own)
        added = interpolate_pose_sequence(own[order].astype(float), self.global_orient[order], self.body_pose[order],
                                          self.transl[order], new.astype(float))
        ids = np.concatenate([own, new])
        rows = np.argsort(ids, kind="stable")

        def merged(mine: np.ndarray, theirs: np.ndarray) -> np.ndarray:
            return np.concatenate([mine, theirs.astype(mine.dtype)])[rows]

        return BodyParams(ids[rows], self.betas, merged(self.global_orient, added["global_orient"]),
                          merged(self.body_pose, added["body_pose"]), merged(self.transl, added["transl"]),
                          self.scale, self.body_model, merged(self.interpolated, np.ones(len(new), bool)))


def read_scene_smpl(path: Path, body_model: str) -> BodyParams:
    """A scene's ``humans/<pid>/smpl.npz`` (validated by the scene reader) as BodyParams."""
    with np.load(path, allow_pickle=False) as data:
        frame_ids = data["frame_ids"].astype(np.int64)
        return BodyParams(frame_ids, data["betas"].astype(np.float64), data["global_orient"].astype(np.float64),
                          data["body_pose"].astype(np.float64), data["transl"].astype(np.float64), 1.0, body_model,
                          np.zeros(len(frame_ids), bool))


def write_body_params(path: Path, params: BodyParams) -> None:
    np.savez(path, format=np.array(BODY_PARAMS_FORMAT), frame_ids=params.frame_ids, betas=params.betas,
             global_orient=params.global_orient, body_pose=params.body_pose, transl=params.transl,
             scale=np.array(params.scale), body_model=np.array(params.body_model), interpolated=params.interpolated)


def read_body_params(path: Path) -> BodyParams:
    """Read a ``body.npz``; refuses other format versions with a clear message."""
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise GlimpseError(f"{path}: cannot read body parameters: {exc}") from None
    with data:
        found = str(data["format"]) if "format" in data.files else None
        if found != BODY_PARAMS_FORMAT:
            raise GlimpseError(f"{path}: format {found!r}; this reader knows {BODY_PARAMS_FORMAT}")
        return BodyParams(data["frame_ids"], data["betas"], data["global_orient"], data["body_pose"],
                          data["transl"], float(data["scale"]), str(data["body_model"]), data["interpolated"])


def read_body_shape(path: Path, num_betas: int, body_model: str) -> np.ndarray:
    """[num_betas] the ``betas`` of an .npz file stating a person's body shape (an earlier run's ``body.npz``,
    or any file with that one array); one clear error naming the file and the rule otherwise. A file that
    names its body model (``body_model``, as body.npz does) must name ``body_model``: betas mean nothing in
    another model's shape space."""
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise GlimpseError(f"{path}: cannot read a body shape ({exc}); give an .npz with `betas`") from None
    with data:
        if "betas" not in data.files:
            raise GlimpseError(f"{path}: no `betas` array (a body shape is an .npz with `betas` [{num_betas}])")
        named = str(data["body_model"]) if "body_model" in data.files else body_model
        betas = np.asarray(data["betas"], dtype=np.float64)
    if named != body_model:
        raise GlimpseError(f"{path}: its betas are for the {named!r} body model; this scene uses {body_model!r}")
    if betas.shape != (num_betas,) or not np.isfinite(betas).all():
        raise GlimpseError(f"{path}: `betas` must be {num_betas} finite numbers, found shape {betas.shape}")
    return betas
