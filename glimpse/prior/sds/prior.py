"""``prior.kind: sds``: score distillation on every person, every iteration (paper Sec. 4.4).

Built once by stage 06 with the shared diffusion models (glimpse/prior/sds/load.py) and each person's
identity from stage 05 (``05_textual_inversion/<pid>/identity/``). From joint iteration ``start_at``
each person gets one SDS step per iteration (supplementary: "we apply SDS loss on all humans who
appeared in the scene"), whether or not the iteration's view shows them:

1. a view kind (cameras.view_kind) and, unless canonical, one of the person's observed poses (its
   refined pose, detached) with the root rotation and translation removed;
2. that posed body (vertices and joints, from the canonical body by the same skinning as the
   Gaussians), an SDS camera around it (cameras.sample_view), the person's Gaussians rendered alone
   over a random colour at ``early_resolution_px`` for their first steps, then ``resolution_px``;
3. the skeleton of that body from that camera, the view's prompts with the person's token, their
   attention processors swapped into the shared UNet, a timestep from the schedule, the SDS loss;
4. plus the hard-surface term of that render's alpha, weighted ``hard_surface`` x lambda_recon (official
   code: lambda_density_reg x lambda_rgb), which pushes the person's coverage towards 0 or 1 in every view.

``combine: summed`` returns the people's SDS losses as one term of the iteration's loss;
``separate_steps`` (official code) hands them to the trainer one person at a time
(:meth:`separate_losses`), each for its own backward pass and that person's optimiser step. The
reconstruction loss is weighted by :meth:`recon_weight` (lambda_recon = recon_scale x tau_max^2).
Everything random is drawn from (seed, iteration, person), so a resumed run repeats its steps.
"""

from __future__ import annotations

import logging

from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from glimpse.body.keypoints import keypoint_map
from glimpse.body.skinning import canonical_to_posed
from glimpse.cameras.model import PinholeCamera, render_camera
from glimpse.errors import GlimpseError
from glimpse.humans.person import PersonGaussians, joint_transforms
from glimpse.io.images import rgb_to_uint8, write_png
from glimpse.metrics.losses import hard_surface_loss
from glimpse.prior.base import PriorContext, UnseenPrior
from glimpse.prior.sds.cameras import sample_view, view_kind
from glimpse.prior.sds.config import DiffusionConfig
from glimpse.prior.sds.control import skeleton_image
from glimpse.prior.sds.guidance import SDSConfig, SDSInfo, SDSText, encode_view_text, sds_loss
from glimpse.prior.sds.identity import IdentitySwitch, load_identity
from glimpse.prior.sds.load import load_diffusion
from glimpse.prior.sds.person_identity import IDENTITY_FILE, unit_image
from glimpse.prior.sds.prompts import view_prompts
from glimpse.prior.sds.schedule import recon_weight, sample_timestep
from glimpse.prior.skeleton import HEAD_JOINT
from glimpse.prior.views import view_word
from glimpse.render import rasterize

PELVIS = 0
STEP_SEED_STRIDE = 1_000_003  # (seed, iteration, person) -> one random stream


log = logging.getLogger("glimpse")


def posed_body(person: PersonGaussians, transforms: Tensor, skin_weights: Tensor) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [V, 3], joints [24, 3]) of the person's body posed by ``transforms [24, 4, 4]``: the canonical
    body moved by the same blend skinning (body model weights ``skin_weights [V, 24]``) as their Gaussians."""
    rig = person.rig
    with torch.no_grad():
        blended = canonical_to_posed(skin_weights, transforms, rig.canonical_transforms)
        vertices = (blended[:, :3, :3] @ rig.canonical_vertices[:, :, None])[..., 0] + blended[:, :3, 3]
        joints = (transforms[:, :3, :3] @ rig.rest_joints[:, :, None])[..., 0] + transforms[:, :3, 3]
    return vertices.double().cpu().numpy(), joints.double().cpu().numpy()


class SDSPrior(UnseenPrior):
    name = "sds"
    section = "diffusion"  # also read by stage 05, which trains the identities
    config_class = DiffusionConfig

    def __init__(self, context: PriorContext, config: DiffusionConfig):
        if context.identity_dir is None:
            raise GlimpseError("prior.kind sds needs stage 05's identities (05_textual_inversion/<pid>/identity/)")
        self.config, self.people, self.seed, self.render = config, list(context.people), context.seed, context.render
        self.device = context.people[0].model.means.device if context.people else torch.device("cpu")
        scaled = context.scaled
        self.start = scaled(config.start_at)
        self.early_steps = scaled(config.early_resolution_steps)
        self.timesteps = replace(config.timesteps, hold_steps=scaled(config.timesteps.hold_steps),
                                 anneal_steps=scaled(config.timesteps.anneal_steps))
        self.cameras = replace(config.cameras, zoom_after=scaled(config.cameras.zoom_after))
        self.preview_every = scaled(config.preview_every) if config.preview_every > 0 else 0
        self.preview_dir = context.preview_dir
        self.models = load_diffusion(config, self.device)
        self.identities = {}
        for person in self.people:
            path = context.identity_dir / person.pid / "identity" / IDENTITY_FILE
            if not path.is_file():
                raise GlimpseError(f"{path}: no identity for {person.pid}; rerun stage 05 with prior.kind sds")
            self.identities[person.pid] = load_identity(self.models, path)
        self.switch = IdentitySwitch(self.models.unet)
        models = {p.pid: context.body_models[p.pid] for p in self.people}  # each person's own model
        self.keypoints = {pid: keypoint_map("openpose18", model.data) for pid, model in models.items()}
        self.skin_weights = {pid: model.weights.to(self.device, torch.float32) for pid, model in models.items()}
        self.labels = context.body_models.default.weights.argmax(dim=1).cpu().numpy()  # body parts, shared
        self.texts: dict[tuple[str, str, str], SDSText] = {}
        self.nonfinite_steps = {person.pid: 0 for person in self.people}  # SDS steps with NaN/inf guidance

    # --- what it reports and what a checkpoint keeps ------------------------------------------------

    def report(self) -> dict:
        return {"guidance_nonfinite_steps": dict(self.nonfinite_steps)}

    def state_dict(self) -> dict:
        return {"nonfinite_steps": dict(self.nonfinite_steps)}

    def load_state_dict(self, state: dict) -> None:
        self.nonfinite_steps.update({pid: int(n) for pid, n in state.get("nonfinite_steps", {}).items()})

    def _count_nonfinite(self, pid: str, step: int, info: SDSInfo) -> None:
        """Guidance that is not finite gives those latents no gradient (SDSInfo): count it, and say so the
        first time for each person (in fp16 it means an overflow: diffusion.half_precision false avoids it)."""
        if info.nonfinite == 0:
            return
        if self.nonfinite_steps[pid] == 0:
            log.warning("sds prior: the diffusion guidance for %s at iteration %d had %d values that are not "
                        "finite (no gradient there); counted in the report as guidance_nonfinite_steps%s", pid,
                        step, info.nonfinite, " (fp16: try diffusion.half_precision false)"
                        if self.models.unet.dtype == torch.float16 else "")
        self.nonfinite_steps[pid] += 1

    # --- schedules ---------------------------------------------------------------------------------

    def recon_weight(self, step: int) -> float:
        return recon_weight(step - self.start, self.timesteps, self.config.recon_scale)

    def _text(self, pid: str, view: str, kind: str) -> SDSText:
        key = (pid, view, kind)
        if key not in self.texts:
            prompts = view_prompts(pid, view, kind, self.config.prompt)
            self.texts[key] = encode_view_text(self.models, prompts.unet, prompts.controlnet, prompts.negative)
        return self.texts[key]

    # --- one person's SDS step -----------------------------------------------------------------------

    def person_loss(self, step: int, index: int) -> Tensor:
        """Person ``index``'s loss in their SDS step at joint iteration ``step`` (>= start_at): the SDS loss plus
        ``hard_surface`` x lambda_recon x the hard-surface term of the same render (official code)."""
        sds, surface = self.person_terms(step, index)
        return sds + self.config.hard_surface * self.recon_weight(step) * surface

    def person_terms(self, step: int, index: int) -> tuple[Tensor, Tensor]:
        """(SDS loss, hard-surface term of the render's alpha) of person ``index`` at joint iteration ``step``,
        unweighted, differentiable in their Gaussians."""
        person, config = self.people[index], self.config
        sds_step = step - self.start
        stream = (self.seed * STEP_SEED_STRIDE + step) * STEP_SEED_STRIDE + index
        rng = np.random.default_rng(stream)
        generator = torch.Generator().manual_seed(stream)
        kind = view_kind(sds_step, self.cameras, rng)
        if kind == "canonical":
            transforms = person.rig.canonical_transforms
        else:
            row = int(rng.integers(len(person.base_pose)))
            pose = (person.base_pose[row] + person.pose_offsets[row]).detach().clone()
            pose[:3] = 0.0
            transforms = joint_transforms(person.rig, pose, torch.zeros(3, device=pose.device), 1.0)
        vertices, joints = posed_body(person, transforms, self.skin_weights[person.pid])
        size = config.early_resolution_px if sds_step < self.early_steps else config.resolution_px
        view = sample_view(kind, self.cameras, vertices, self.labels, joints[PELVIS], 1.0, size, rng)
        camera = render_camera(view.camera, self.device)
        posed = person.posed_with(transforms, camera.centre, self.render.sh_degree)
        background = torch.as_tensor(rng.random(3), dtype=torch.float32, device=self.device)
        render = rasterize(camera, means=posed.means, covariances=posed.covariances, opacities=posed.opacities,
                           colors=posed.colors, background=background, settings=self.render)
        skeleton = self._skeleton(person.pid, vertices, joints, view.camera)
        prompt_view = view_word(view.azimuth_deg, config.prompt.front_max_deg, config.prompt.back_min_deg)
        timestep = sample_timestep(sds_step, self.timesteps, self.models.train_timesteps, generator)
        self.switch.use(self.identities[person.pid])
        rgb = render.rgb.permute(2, 0, 1)[None]
        preview = self.preview_dir is not None and self.preview_every > 0 and sds_step % self.preview_every == 0
        loss, info = sds_loss(self.models, rgb, skeleton, self._text(person.pid, prompt_view, kind), timestep,
                              generator, SDSConfig(config.guidance_scale, config.controlnet_scale,
                                                   config.resolution_px), preview)
        self._count_nonfinite(person.pid, step, info)
        if info.preview is not None:
            self._write_preview(self.preview_dir / person.pid / f"{step:06d}.png", rgb, skeleton, info.preview)
        return loss, hard_surface_loss(render.alpha)

    @staticmethod
    @torch.no_grad()
    def _write_preview(path: Path, rgb: Tensor, skeleton: Tensor, guess: Tensor) -> None:
        """render | skeleton | denoised guess side by side, each [1, 3, *, *] in 0..1, at the guess's size."""
        size = guess.shape[-2:]
        tiles = [F.interpolate(rgb.detach().float(), size=size, mode="bilinear", align_corners=False),
                 F.interpolate(skeleton.float(), size=size, mode="nearest"), guess.float()]
        write_png(path, rgb_to_uint8(torch.cat(tiles, dim=-1)[0].permute(1, 2, 0)))

    def _skeleton(self, pid: str, vertices: np.ndarray, joints: np.ndarray, camera: PinholeCamera) -> Tensor:
        """[1, 3, R, R] person ``pid``'s OpenPose skeleton in 0..1 at the diffusion resolution R, from ``camera``."""
        resolution = self.config.resolution_px
        with torch.no_grad():
            keypoints = self.keypoints[pid](torch.as_tensor(joints[None]), torch.as_tensor(vertices[None]))[0].numpy()
        image, _, _ = skeleton_image(keypoints, joints[HEAD_JOINT], camera.resized(resolution, resolution), resolution,
                                     self.config.skeleton_line_px)
        return unit_image(image)[None].to(self.device)

    # --- the prior's interface ------------------------------------------------------------------------

    def losses(self, step: int, people: Sequence[PersonGaussians]) -> dict[str, Tensor]:
        if self.config.combine != "summed" or step < self.start or not self.people:
            return {}
        return {"loss_sds": torch.stack([self.person_loss(step, k) for k in range(len(self.people))]).sum()}

    def separate_losses(self, step: int) -> Iterator[tuple[int, Tensor]]:
        if self.config.combine != "separate_steps" or step < self.start:
            return
        for index in range(len(self.people)):
            yield index, self.person_loss(step, index)
