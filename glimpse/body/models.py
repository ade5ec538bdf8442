"""Each person's body model: the shared file (``body.model_path``) for everyone, except the people that
``body.person_model_paths`` gives their own file (gendered SMPL: a man and a woman in one scene).

Every file must share the shared model's topology (vertices, faces, joint tree), so that what is
computed on one person's mesh (skin weights, visibility, rasterized meshes) means the same on another's.
Each distinct file is loaded once.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from glimpse.body.config import BodyConfig, resolve_model_path, resolve_person_model_paths
from glimpse.body.model import BodyModel
from glimpse.errors import GlimpseError


class BodyModels:
    """pid -> BodyModel. ``default`` is the shared model; ``faces`` are every model's."""

    def __init__(self, default: BodyModel, own: dict[str, BodyModel] | None = None):
        self.default = default
        self.own = dict(own or {})
        for pid, model in self.own.items():
            _check_topology(default, model, pid)

    @classmethod
    def load(cls, config: BodyConfig, dtype: torch.dtype = torch.float32) -> BodyModels:
        """The shared model and each person's own, every distinct file read once."""
        default_path = resolve_model_path(config)
        loaded: dict[Path, BodyModel] = {default_path: BodyModel.from_file(default_path, dtype=dtype)}
        own = {}
        for pid, path in resolve_person_model_paths(config).items():
            if path not in loaded:
                loaded[path] = BodyModel.from_file(path, dtype=dtype)
            own[pid] = loaded[path]
        return cls(loaded[default_path], own)

    def __getitem__(self, pid: str) -> BodyModel:
        return self.own.get(pid, self.default)

    @property
    def faces(self) -> torch.Tensor:
        """[F, 3] long: the faces every person's model shares."""
        return self.default.faces


def _check_topology(default: BodyModel, model: BodyModel, pid: str) -> None:
    same = (model.num_vertices == default.num_vertices and tuple(model.parents.tolist()) == tuple(default.parents.tolist())
            and model.faces.shape == default.faces.shape
            and np.array_equal(model.faces.cpu().numpy(), default.faces.cpu().numpy()))
    if not same:
        raise GlimpseError(
            f"body.person_model_paths ({pid}): {model.data.source} does not share the topology of body.model_path "
            f"({default.data.source}: {default.num_vertices} vertices, {len(default.faces)} faces); a person's own "
            "model must be another variant of the same model (e.g. SMPL's male or female beside its neutral)"
        )
