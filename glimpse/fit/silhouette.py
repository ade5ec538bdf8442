"""The silhouette term of a 2D fit: the body's outline against the person's mask.

Keypoints fix a skeleton, and only where they are: COCO-17 has no top of the head and no feet, a limb whose
keypoints a detector lost is left to the pose prior, and each keypoint carries its own noise. A person's mask shows
the whole body: every point of the body must project onto a pixel that may show the person (their own mask, or
another person's, who may hide them), and every pixel of their mask must be covered by the body. Both are measured
on a fixed set of surface points of the body (``SurfaceBody``, farthest-point samples of its vertices, posed exactly
as the body model poses them):

- outside: for each point, the distance in pixels from where it projects to the nearest pixel that may show
  the person (a distance transform of the masks, sampled bilinearly); points whose keypoints are not seen in
  the frame (legs a table hides) and points outside the image count nothing;
- coverage: for each of a fixed set of pixels on the mask's outline, the distance to the nearest projected
  surface point, less a tolerance: half the points' spacing (a perfect fit's outline lies between points) and an
  optional allowance for clothes and hair, which stand off the body.

Both are converted to metres at the person as keypoint residuals are (pixels times depth / focal length), and
weighed by a Geman-McClure robust square (glimpse.fit.objective.data_energy): a mask that takes in part of
someone else, or clothes that stand off the body, pull little.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage
from torch import Tensor

from glimpse.body.lbs import batch_rigid_transform, batch_rodrigues, blend_shapes, pose_features, skin_vertices
from glimpse.body.model import BodyModel


class SurfaceBody(torch.nn.Module):
    """``scale * posed + transl`` of a subset of the body model's vertices, exactly as BodyModel poses them
    (shape and pose blend shapes, linear blend skinning), without posing the others."""

    def __init__(self, model: BodyModel, vertex_indices: np.ndarray):
        super().__init__()
        idx = torch.as_tensor(vertex_indices, dtype=torch.long)
        self._parents = tuple(int(p) for p in model.parents.tolist())
        self.register_buffer("joint_template", model.J_regressor @ model.v_template)  # [24, 3]
        self.register_buffer("joint_shapedirs", torch.einsum("jv,vcs->jcs", model.J_regressor, model.shapedirs))
        self.register_buffer("template", model.v_template[idx])  # [S, 3]
        self.register_buffer("shapedirs", model.shapedirs[idx])  # [S, 3, betas]
        self.register_buffer("posedirs", model.posedirs[idx])  # [S, 3, 207]
        self.register_buffer("weights", model.weights[idx])  # [S, 24]

    def spacing_m(self) -> float:
        """The median distance from each rest-pose point to its nearest neighbour (metres, template shape)."""
        points = self.template.double()
        distance = torch.cdist(points, points)
        distance.fill_diagonal_(float("inf"))
        return float(distance.min(1).values.median())

    def forward(self, betas: Tensor, global_orient: Tensor, body_pose: Tensor, transl: Tensor,
                scale: Tensor) -> Tensor:
        """betas [10] (shared) or [B, 10]; global_orient [B, 3]; body_pose [B, 69]; transl [B, 3]; scale [] or [B]
        -> [B, S, 3] world units."""
        batch = global_orient.shape[0]
        betas_b = betas.expand(batch, -1) if betas.ndim == 1 else betas
        rest_joints = self.joint_template + torch.einsum("jcs,bs->bjc", self.joint_shapedirs, betas_b)
        rotations = batch_rodrigues(torch.cat([global_orient, body_pose], 1).reshape(batch, -1, 3))
        _, transforms = batch_rigid_transform(rotations, rest_joints, self._parents)
        rest = (self.template + blend_shapes(betas_b, self.shapedirs)
                + blend_shapes(pose_features(rotations), self.posedirs))
        points = skin_vertices(self.weights, transforms, rest)
        s = scale.reshape(-1, 1, 1) if scale.ndim else scale
        return s * points + transl[:, None, :]


def linked_keypoints(points: np.ndarray, keypoints: np.ndarray, count: int) -> np.ndarray:
    """[S, count] the ``count`` keypoints [K, 3] nearest each surface point [S, 3] (rest pose): a point counts in
    a frame only where all of them are seen."""
    distance = ((points[:, None] - keypoints[None]) ** 2).sum(-1)
    return np.argsort(distance, axis=1, kind="stable")[:, :count]


@dataclass(frozen=True)
class SilhouetteEvidence:
    """One person's masks on the F frames the term uses.

    rows [F] long: the frames' indices in the track; frame_weight: every used frame stands for this many
    fitted frames; outside_px [F, h, w]: distance, in full-size pixels, from each working pixel to the nearest
    one that may show the person (0 there); downsample d: full-size pixel u lies at working (u - (d - 1) / 2) / d;
    image_size (width, height) full-size pixels; edges_px [F, E, 2] full-size pixel coordinates of points on
    the person's mask outline, edge_weight [F, E] (0: padding)."""

    rows: Tensor
    frame_weight: float
    outside_px: Tensor
    downsample: int
    image_size: tuple[int, int]
    edges_px: Tensor
    edge_weight: Tensor


def working_masks(mask: np.ndarray, downsample: int) -> np.ndarray:
    """[H, W] bool -> [ceil(H / d), ceil(W / d)] bool, a working pixel set where any of its pixels is."""
    if downsample == 1:
        return mask
    height, width = mask.shape
    padded = np.zeros((-(-height // downsample) * downsample, -(-width // downsample) * downsample), bool)
    padded[:height, :width] = mask
    return padded.reshape(padded.shape[0] // downsample, downsample, -1, downsample).any((1, 3))


def outline_points(mask: np.ndarray, count: int) -> np.ndarray:
    """[<= count, 2] (x, y) working pixels of the mask's outline (pixels of the mask with a 4-neighbour outside
    it), evenly spaced along the outline's raster order."""
    inner = ndimage.binary_erosion(mask, structure=ndimage.generate_binary_structure(2, 1), border_value=0)
    ys, xs = np.nonzero(mask & ~inner)
    if len(xs) > count:
        keep = np.linspace(0, len(xs) - 1, count).round().astype(np.int64)
        ys, xs = ys[keep], xs[keep]
    return np.stack([xs, ys], 1).astype(np.float64)


def silhouette_evidence(rows: np.ndarray, own: list[np.ndarray], others: list[np.ndarray], frame_weight: float,
                        max_side_px: int, edge_count: int, dtype: torch.dtype) -> SilhouetteEvidence:
    """The term's evidence from the person's masks ``own`` and the union of everyone else's ``others`` (lists of
    [H, W] bool, one per row of ``rows`` [F]), worked on at most ``max_side_px`` on a side."""
    height, width = own[0].shape
    d = max(1, -(-max(height, width) // max_side_px))
    distances, edges, edge_weight = [], np.zeros((len(rows), edge_count, 2)), np.zeros((len(rows), edge_count))
    for f, (mine, theirs) in enumerate(zip(own, others, strict=True)):
        may_show = working_masks(mine | theirs, d)
        distances.append(ndimage.distance_transform_edt(~may_show) * d if may_show.any()
                         else np.zeros(may_show.shape))
        outline = outline_points(working_masks(mine, d), edge_count)
        edges[f, :len(outline)] = outline * d + (d - 1) / 2
        edge_weight[f, :len(outline)] = 1.0
    return SilhouetteEvidence(torch.as_tensor(rows, dtype=torch.long), float(frame_weight),
                              torch.as_tensor(np.stack(distances), dtype=dtype), d, (width, height),
                              torch.as_tensor(edges, dtype=dtype), torch.as_tensor(edge_weight, dtype=dtype))


def sample_outside_px(evidence: SilhouetteEvidence, pixels: Tensor) -> Tensor:
    """pixels [F, S, 2] full-size -> [F, S] the distance to the nearest pixel that may show the person (bilinear,
    differentiable in the pixels)."""
    d, (_, h, w) = evidence.downsample, evidence.outside_px.shape
    working = (pixels - (d - 1) / 2) / d
    grid = torch.stack([2 * working[..., 0] / max(w - 1, 1) - 1, 2 * working[..., 1] / max(h - 1, 1) - 1], -1)
    sampled = torch.nn.functional.grid_sample(evidence.outside_px[:, None], grid[:, None], mode="bilinear",
                                              padding_mode="border", align_corners=True)
    return sampled[:, 0, 0]


def in_image(pixels: Tensor, depth: Tensor, image_size: tuple[int, int]) -> Tensor:
    """[F, S] bool: in front of the camera and inside the image (pixel centres 0 .. size - 1, half a pixel more)."""
    width, height = image_size
    x, y = pixels[..., 0], pixels[..., 1]
    return (depth > 0) & (x >= -0.5) & (x <= width - 0.5) & (y >= -0.5) & (y <= height - 0.5)


def silhouette_residuals_px(evidence: SilhouetteEvidence, pixels: Tensor,
                            depth: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Projected surface points pixels [F, S, 2] with depths [F, S] -> (outside [F, S], coverage [F, E], inside
    [F, S] bool), pixels: each point's distance outside what may show the person; each outline pixel's distance
    to the nearest projected point in the image (0 in a frame with none there); which points are in the image."""
    inside = in_image(pixels, depth, evidence.image_size)
    outside = sample_outside_px(evidence, pixels)
    with torch.no_grad():  # which projected point is nearest each outline pixel (the distance to it is differentiated
        # below): |p|^2 - 2 e.p orders the points as |e - p|^2 does, and single precision is ample for that
        edges, points = evidence.edges_px.float(), pixels.float()
        order = torch.baddbmm(points.square().sum(-1)[:, None], edges, points.transpose(1, 2), alpha=-2.0)  # [F, E, S]
        nearest = order.masked_fill_(~inside[:, None], torch.inf).argmin(-1)  # [F, E]
    reached = torch.gather(pixels, 1, nearest[..., None].expand(-1, -1, 2))  # [F, E, 2]
    coverage = (evidence.edges_px - reached).norm(dim=-1)
    return outside, torch.where(inside.any(-1, keepdim=True), coverage, torch.zeros_like(coverage)), inside
