"""``prior.kind: surface``: complete each person without diffusion weights (docs/prior.md).

What the input views saw of each person is known per body vertex (glimpse.humans.visibility); each
canonical Gaussian belongs to its nearest Da-pose body vertex, and is *unseen* when that vertex was
seen in fewer than ``min_seen_frames`` input frames. Five weighted terms, every iteration from
``start_at`` on, for the people of the view:

- ``loss_prior_colour``: each unseen Gaussian's base colour (SH DC) against a completed colour of its
  vertex, plus ``view_dependent`` x its higher SH coefficients (no view taught them anything). The
  completed colours are recomputed at most every ``refresh_every`` iterations: the opacity-weighted
  mean colour of the Gaussians of each vertex seen within ``colour_max_angle_deg`` of head-on, held
  with a confidence of ``colour_confidence`` x their opacity sum (faint Gaussians' colours yield to
  their neighbours), extended to the rest of the body over the mesh plus left-right mirror edges,
  pulled with ``part_anchor`` towards the seen mean of the vertex's body part, or of its nearest
  seen ancestor part, both weighted by opacity (glimpse.prior.complete); with ``garments``, on the
  torso, arms and legs, towards skin or the zone's garment instead (glimpse.prior.garments). With
  ``grazing_colour``, the Gaussians of vertices seen only beyond ``colour_max_angle_deg`` are pulled
  to the completed colour too. ``loss_prior_seen_colour`` (weight ``seen_colour``) pulls every other
  Gaussian towards its vertex's completed colour (there, its own opacity-weighted mean held against its
  neighbours'): colour variation finer than that, which a person seen small cannot show the input, is
  evened out.
- ``loss_prior_surface``: unseen Gaussians further than ``surface_margin_m`` from their vertex, squared
  excess over the margin squared; nothing else holds them on the body.
- ``loss_prior_needle``: every Gaussian whose largest scale exceeds ``needle_ratio`` times its middle
  one, by how much: the needles ("hedgehogs", paper Fig. 3) a single view leaves behind.
- ``loss_prior_silhouette``: one person (in turn) rendered alone in the canonical frame from one of
  ``views_per_person`` fixed random orbit cameras (glimpse.cameras.orbit), against that view's body
  silhouette: transparency inside the silhouette shrunk by ``silhouette_margin_m`` (holes) weighted
  ``silhouette_fill``, opacity outside it grown by the margin (spikes, floaters) ``silhouette_trim``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from glimpse.body.symmetry import mesh_edges, mirror_vertex_map
from glimpse.cameras.model import render_camera
from glimpse.cameras.orbit import box_centre, sample_orbit_views
from glimpse.humans.person import PersonGaussians
from glimpse.morphology import disk
from glimpse.prior.base import PriorContext, UnseenPrior
from glimpse.prior.complete import body_graph, part_groups, part_means, part_parents, screened_fill
from glimpse.prior.config import SurfacePriorConfig
from glimpse.prior.garments import BodyZones, body_zones, garment_anchors
from glimpse.render import Camera, rasterize
from glimpse.render.mesh_raster import rasterize_triangles
from glimpse.render.sh import sh_dc_to_rgb

VIEW_SEED_OFFSET = 7_919  # separates the orbit bank's random stream from the run's other streams


@dataclass
class SilhouetteView:
    """One orbit camera around a person's canonical body and its targets, [S, S] bool each."""

    camera: Camera
    inside: Tensor  # the body's silhouette shrunk by the margin: should be opaque
    outside: Tensor  # outside the silhouette grown by the margin: should be empty


@dataclass
class PersonPrior:
    """Per person: the canonical vertices [V, 3] (tree for nearest-vertex lookups), which vertices the
    input views saw [V], the completed vertex colours [V, 3] and the iteration they were computed at
    (0: never), the nearest vertex of each Gaussian [N] (None: recompute), and the silhouette views."""

    tree: cKDTree
    vertices: Tensor
    seen: Tensor
    colour_source: Tensor  # [V] bool: seen head-on enough to lend its colour
    zones: BodyZones  # where skin or garments continue (glimpse.prior.garments)
    vertex_colours: Tensor
    coloured_at: int
    nearest: Tensor | None
    views: list[SilhouetteView]


class SurfacePrior(UnseenPrior):
    name = "surface"
    section = "prior_surface"
    config_class = SurfacePriorConfig

    def __init__(self, context: PriorContext, config: SurfacePriorConfig):
        self.config, self.render, self.scaled, self.seed = config, context.render, context.scaled, context.seed
        shared = context.body_models.default  # the topology and body parts every person's model shares
        faces = shared.faces.cpu().numpy()
        mirror, _ = mirror_vertex_map(shared.v_template.double().cpu().numpy())
        self.graph = body_graph(mesh_edges(faces), mirror, config.mirror_weight, shared.num_vertices)
        labels = shared.weights.argmax(dim=1).cpu().numpy()
        self.groups = part_groups(labels, mirror)
        self.parent_group = part_parents(labels, self.groups, shared.parents.cpu().numpy())
        min_cosine = math.cos(math.radians(config.colour_max_angle_deg))
        rng = np.random.default_rng(context.seed + VIEW_SEED_OFFSET)
        self.people: dict[str, PersonPrior] = {}
        for person in context.people:
            vertices = person.rig.canonical_vertices.detach()
            record = context.visibility[person.pid]
            seen = torch.as_tensor(record.seen_frames >= config.min_seen_frames, device=vertices.device)
            source = seen & torch.as_tensor(record.best_cosine >= min_cosine, device=vertices.device)
            points = vertices.double().cpu().numpy()
            self.people[person.pid] = PersonPrior(
                cKDTree(points), vertices, seen, source, body_zones(labels, points), torch.zeros_like(vertices), 0,
                None, self._silhouette_views(vertices, faces, rng))

    def _silhouette_views(self, vertices: Tensor, faces: np.ndarray, rng: np.random.Generator) -> list[SilhouetteView]:
        points = vertices.double().cpu().numpy()
        centre = box_centre(points)
        orbit, device = self.config.orbit, vertices.device
        margin_px = self.config.silhouette_margin_m * (0.5 * orbit.size_px / np.tan(np.radians(orbit.fovy_deg) / 2)
                                                       ) / orbit.radius_m
        views = []
        for view in sample_orbit_views(centre, self.config.views_per_person, orbit, rng):
            cam = view.camera
            body = rasterize_triangles(points @ cam.R.T + cam.t, faces, cam.K, cam.width, cam.height).face >= 0
            views.append(SilhouetteView(
                render_camera(cam, device),
                torch.as_tensor(disk(body, margin_px, grow=False), device=device),
                torch.as_tensor(~disk(body, margin_px, grow=True), device=device)))
        return views

    # --- cached state ------------------------------------------------------------------------------

    def gaussians_changed(self, person: PersonGaussians) -> None:
        self.people[person.pid].nearest = None

    def _nearest(self, person: PersonGaussians) -> Tensor:
        state = self.people[person.pid]
        if state.nearest is None or len(state.nearest) != len(person.model):
            _, index = state.tree.query(person.model.means.detach().double().cpu().numpy())
            state.nearest = torch.as_tensor(index, dtype=torch.long, device=person.model.means.device)
        return state.nearest

    @torch.no_grad()
    def _refresh_colours(self, person: PersonGaussians, step: int) -> None:
        """The seen vertices' colours from their Gaussians, completed over the rest of the body."""
        state = self.people[person.pid]
        previous = state.vertex_colours.double().cpu().numpy() if state.coloured_at > 0 else None
        state.nearest, state.coloured_at = None, step
        nearest = self._nearest(person)
        weights = person.model.opacities().detach()
        colours = sh_dc_to_rgb(person.model.sh_dc.detach()[:, 0]).clamp(0.0, 1.0)
        count = len(state.vertices)
        total = torch.zeros(count, 3, device=weights.device).index_add_(0, nearest, colours * weights[:, None])
        mass = torch.zeros(count, device=weights.device).index_add_(0, nearest, weights)
        known = (state.colour_source & (mass > 0)).cpu().numpy()
        mean = (total / mass.clamp(min=1e-12)[:, None]).double().cpu().numpy()
        opacity_mass = mass.double().cpu().numpy()
        config = self.config
        anchors = part_means(mean, known, self.groups, self.parent_group, config.part_min_seen, opacity_mass)
        if config.garments:
            anchors = garment_anchors(mean, known, opacity_mass, state.zones, self.groups, anchors,
                                      config.skin_colour_distance, config.skin_reach_m,
                                      np.asarray(config.neutral_garment))
        confidence = np.where(known, config.colour_confidence * opacity_mass, 0.0)
        filled = screened_fill(mean, confidence, self.graph, anchors, config.part_anchor, initial=previous)
        state.vertex_colours = torch.as_tensor(filled, dtype=torch.float32, device=weights.device)

    def state_dict(self) -> dict:
        return {pid: {"vertex_colours": p.vertex_colours.cpu(), "coloured_at": p.coloured_at,
                      "nearest": None if p.nearest is None else p.nearest.cpu()} for pid, p in self.people.items()}

    def load_state_dict(self, state: dict) -> None:
        for pid, saved in state.items():
            person = self.people[pid]
            person.vertex_colours = saved["vertex_colours"].to(person.vertices.device)
            person.coloured_at = int(saved["coloured_at"])
            person.nearest = None if saved["nearest"] is None else saved["nearest"].to(person.vertices.device)

    # --- the losses --------------------------------------------------------------------------------

    def losses(self, step: int, people: Sequence[PersonGaussians]) -> dict[str, Tensor]:
        config = self.config
        start = self.scaled(config.start_at)
        if step < start or not people:
            return {}
        for person in people:
            coloured_at = self.people[person.pid].coloured_at
            if coloured_at == 0 or step - coloured_at >= self.scaled(config.refresh_every):
                self._refresh_colours(person, step)
        terms: dict[str, list[Tensor]] = {"colour": [], "seen_colour": [], "surface": [], "needle": []}
        for person in people:
            colour, seen_colour, surface = self._colour_and_surface_terms(person)
            terms["colour"].append(colour)
            terms["seen_colour"].append(seen_colour)
            terms["surface"].append(surface)
            terms["needle"].append(self._needle_term(person))
        weights = {"colour": config.colour, "seen_colour": config.seen_colour, "surface": config.surface,
                   "needle": config.needle}
        out = {f"loss_prior_{name}": weights[name] * torch.stack(values).sum()
               for name, values in terms.items() if weights[name] > 0}
        if config.silhouette_fill > 0 or config.silhouette_trim > 0:
            out["loss_prior_silhouette"] = self._silhouette_term(step, people[step % len(people)])
        return out

    def _colour_and_surface_terms(self, person: PersonGaussians) -> tuple[Tensor, Tensor, Tensor]:
        """(colour term, seen-colour term, surface term): the colour and surface terms of the person's unseen
        Gaussians (zero when every one was seen); with ``grazing_colour``, the colour term also covers the
        Gaussians of vertices seen only at grazing angles (they lend no colour either: their own came from the
        edge of a silhouette); the seen-colour term covers the others."""
        state, model = self.people[person.pid], person.model
        nearest = self._nearest(person)
        unseen = ~state.seen[nearest]
        pulled = ~state.colour_source[nearest] if self.config.grazing_colour else unseen
        zero = model.means.sum() * 0.0
        colour = seen_colour = surface = zero
        # every Gaussian's colour error in one pass, the two terms' Gaussians as 0/1 weights: cheaper than subsets
        error = (sh_dc_to_rgb(model.sh_dc[:, 0]) - state.vertex_colours[nearest]).square().sum(1)
        weight = pulled.to(error.dtype)
        pulled_count = int(pulled.sum())
        if self.config.seen_colour > 0 and pulled_count < len(pulled):
            seen_colour = (error * (1.0 - weight)).sum() / (len(pulled) - pulled_count)
        if pulled_count:
            colour = (error * weight).sum() / pulled_count
            if model.sh_rest.shape[1] > 0 and self.config.view_dependent > 0:
                colour = colour + self.config.view_dependent * model.sh_rest[pulled].square().sum((1, 2)).mean()
        if unseen.any():
            distance = (model.means[unseen] - state.vertices[nearest[unseen]]).norm(dim=1)
            margin = self.config.surface_margin_m
            surface = ((distance - margin).clamp(min=0.0) / margin).square().mean()
        return colour, seen_colour, surface

    def _needle_term(self, person: PersonGaussians) -> Tensor:
        scales = person.model.scales().sort(dim=1).values  # ascending
        ratio = scales[:, 2] / scales[:, 1].clamp(min=1e-9)
        return (ratio - self.config.needle_ratio).clamp(min=0.0).mean()

    def _silhouette_term(self, step: int, person: PersonGaussians) -> Tensor:
        """The person alone, canonical frame, from one of their orbit views chosen by ``step``."""
        views = self.people[person.pid].views
        generator = torch.Generator().manual_seed(self.seed * 1_000_003 + step)
        view = views[int(torch.randint(len(views), (1,), generator=generator))]
        model = person.model
        out = rasterize(view.camera, means=model.means, opacities=model.opacities(), quats=model.quats,
                        scales=model.scales(), colors=sh_dc_to_rgb(model.sh_dc[:, 0]).clamp(0.0, 1.0),
                        settings=self.render)
        fill = (1.0 - out.alpha[view.inside]).mean() if view.inside.any() else out.alpha.sum() * 0.0
        trim = out.alpha[view.outside].mean() if view.outside.any() else out.alpha.sum() * 0.0
        return self.config.silhouette_fill * fill + self.config.silhouette_trim * trim
