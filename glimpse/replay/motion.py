"""A new motion for a person of a finished run, placed in the scene (CONTRACTS.md "New motion in a
scene").

The motion (glimpse.body.motion: AMASS-style z up, smplx-style or built-in y up) is first turned so
its up axis is the body's canonical up (+y). Its root trajectory is then taken relative to its
first frame: the point on its ground under the pelvis, and its heading (the body's forward, +z,
flattened onto the ground). That frame is laid onto the person's at the chosen scene frame: the
point on the person's ground under their pelvis, their heading flattened onto their ground, and
their scale (world units per metre). The person's ground is estimated from their body over the
video: its normal is the mean canonical up of the fitted bodies (people stand upright), its height
the median over frames of the lowest body point along it (the feet). The motion's ground is its
median lowest body point the same way. The person keeps their shape (betas).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from glimpse.body.model import BodyModel
from glimpse.body.motion import BodySequence, builtin_motion, load_motion
from glimpse.body.params import BodyParams
from glimpse.errors import GlimpseError

CANONICAL_UP = np.array([0.0, 1.0, 0.0])
CANONICAL_FORWARD = np.array([0.0, 0.0, 1.0])
Z_UP_TO_Y_UP = Rotation.from_euler("x", -90.0, degrees=True)  # (x, y, z) -> (x, z, -y): z up becomes y up


def motion_from_spec(source: str, fps: float, builtin_seconds: float) -> BodySequence:
    """``builtin:NAME`` (``builtin_seconds`` of a built-in motion) or a motion .npz path (AMASS-style or
    smplx-style), at ``fps``."""
    if source.startswith("builtin:"):
        return builtin_motion(source.removeprefix("builtin:"), max(1, round(builtin_seconds * fps)), fps)
    return load_motion(source, target_fps=fps)


@dataclass(frozen=True)
class GroundFrame:
    """A point on a ground plane and a rotation whose columns are (left, up, forward) there."""

    origin: np.ndarray  # (3,)
    axes: np.ndarray  # (3, 3)


def lowest_points(body_model: BodyModel, betas: np.ndarray, global_orient: np.ndarray, body_pose: np.ndarray,
                  transl: np.ndarray, scale: float, up: np.ndarray) -> np.ndarray:
    """[T] per frame, the lowest body vertex's height along ``up`` (world units)."""
    with torch.no_grad():
        out = body_model(torch.as_tensor(betas), torch.as_tensor(global_orient), torch.as_tensor(body_pose),
                         torch.as_tensor(transl), scale=scale)
    return (out.vertices.double().numpy() @ up).min(axis=1)


def heading_frame(origin: np.ndarray, up: np.ndarray, root_rotation: np.ndarray) -> GroundFrame:
    """The ground frame at ``origin`` with the root's forward flattened onto the plane normal to ``up``."""
    forward = root_rotation @ CANONICAL_FORWARD
    forward = forward - (forward @ up) * up
    if np.linalg.norm(forward) < 1e-6:  # lying face up or down: take the body's up instead
        forward = root_rotation @ CANONICAL_UP
        forward = forward - (forward @ up) * up
    forward /= np.linalg.norm(forward)
    return GroundFrame(origin, np.stack([np.cross(up, forward), up, forward], axis=1))


def upright(motion: BodySequence, rest_pelvis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(global_orient [T, 3], transl [T, 3]) of the motion with +y up (a z-up motion turned about the origin,
    the pelvis at ``rest_pelvis`` in the model frame)."""
    if motion.up_axis == "y":
        return motion.global_orient, motion.transl
    turned = Z_UP_TO_Y_UP * Rotation.from_rotvec(motion.global_orient)
    pelvis = Z_UP_TO_Y_UP.apply(motion.transl + rest_pelvis)
    return turned.as_rotvec(), pelvis - rest_pelvis


def retarget(motion: BodySequence, person: BodyParams, frame_id: int, body_model: BodyModel,
             frame_ids: np.ndarray) -> BodyParams:
    """The person's body driven by ``motion`` from their place and heading at ``frame_id``, one motion frame
    per entry of ``frame_ids`` (the motion's first ``len(frame_ids)`` frames, its last one held after)."""
    if int(frame_id) not in set(person.frame_ids.tolist()):
        raise GlimpseError(f"the person has no body at frame {frame_id}: the motion has nowhere to start")
    betas = person.betas
    with torch.no_grad():
        rest_pelvis = body_model(torch.as_tensor(betas), torch.zeros(1, 3, dtype=body_model.v_template.dtype),
                                 torch.zeros(1, 69, dtype=body_model.v_template.dtype)).joints[0, 0].double().numpy()
    steps = np.minimum(np.arange(len(frame_ids)), len(motion) - 1)
    orient, transl = upright(motion, rest_pelvis)
    orient, transl, pose = orient[steps], transl[steps], motion.body_pose[steps]

    # the person's ground and frame at frame_id (world)
    rotations = Rotation.from_rotvec(person.global_orient).as_matrix()
    up = (rotations @ CANONICAL_UP).mean(axis=0)
    up /= np.linalg.norm(up)
    ground = np.median(lowest_points(body_model, betas, person.global_orient, person.body_pose, person.transl,
                                     person.scale, up))
    row = int(np.nonzero(person.frame_ids == frame_id)[0][0])
    pelvis = person.scale * rest_pelvis + person.transl[row]
    target = heading_frame(pelvis - (pelvis @ up - ground) * up, up, rotations[row])

    # the motion's ground and frame at its first frame (metres, y up)
    motion_ground = np.median(lowest_points(body_model, betas, orient, pose, transl, 1.0, CANONICAL_UP))
    first_pelvis = rest_pelvis + transl[0]
    source = heading_frame(first_pelvis - (first_pelvis[1] - motion_ground) * CANONICAL_UP, CANONICAL_UP,
                           Rotation.from_rotvec(orient[0]).as_matrix())

    carry = target.axes @ source.axes.T  # motion frame -> world, a rotation
    world_pelvis = target.origin + person.scale * ((rest_pelvis + transl - source.origin) @ carry.T)
    world_orient = (Rotation.from_matrix(carry) * Rotation.from_rotvec(orient)).as_rotvec()
    return BodyParams(np.asarray(frame_ids), betas, world_orient, pose, world_pelvis - person.scale * rest_pelvis,
                      person.scale, person.body_model, np.zeros(len(frame_ids), bool))
