"""The C++ training-time posing (csrc/skinning_cpu.cpp) against PersonGaussians.posed_with's PyTorch path:
posed means, covariances and colours, and the gradients of a random loss with respect to every Gaussian
parameter and the pose."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from glimpse.body.config import BodyConfig, resolve_model_path
from glimpse.body.model import BodyModel
from glimpse.body.params import BodyParams
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.humans.person import initial_person
from glimpse.render import composite_cpu

pytestmark = pytest.mark.skipif(not composite_cpu.available(), reason="the C++ kernel does not build here")
BODY = config_from_mapping(BodyConfig, load_pipeline_yaml()["body"], "body")
GRAD_REL = 2e-4


def posed_and_grads(person, degree: int, seed: int) -> tuple[dict, dict]:
    for tensor in (*person.model.parameter_dict().values(), person.pose_offsets):
        tensor.grad = None
    out = person.posed(1, torch.tensor([0.3, -0.2, 4.0]), degree)
    g = torch.Generator().manual_seed(seed)
    loss = sum((getattr(out, name) * torch.randn(getattr(out, name).shape, generator=g)).sum()
               for name in ("means", "covariances", "colors"))
    loss.backward()
    values = {name: getattr(out, name).detach().clone() for name in ("means", "covariances", "colors")}
    grads = {name: p.grad.clone() for name, p in person.model.parameter_dict().items() if p.grad is not None}
    grads["pose_offsets"] = person.pose_offsets.grad.clone()
    return values, grads


@pytest.mark.parametrize("degree", [0, 3])
def test_training_posing_matches_the_pytorch_path(degree, monkeypatch):
    body_model = BodyModel.from_file(resolve_model_path(BODY))
    rng = np.random.default_rng(degree)
    body = BodyParams(np.arange(2), rng.normal(0, 0.5, 10), rng.normal(0, 0.4, (2, 3)), rng.normal(0, 0.3, (2, 69)),
                      rng.normal(0, 1.0, (2, 3)), 1.3, "free", np.zeros(2, bool))
    person = initial_person("p0", body_model, body, BODY.canonical_hip_angle_deg, BODY.skinning, 0.5, 0.9, 3, 3)
    with torch.no_grad():  # anisotropic, turned, coloured from every direction, some means off the body
        person.model.sh_rest.normal_(0.0, 0.2, generator=torch.Generator().manual_seed(degree))
        person.model.quats.copy_(torch.as_tensor(rng.normal(size=(len(person.model), 4))))
        person.model.log_scales.add_(torch.as_tensor(rng.normal(0.0, 0.5, (len(person.model), 3)), dtype=torch.float32))
        person.model.means.add_(torch.as_tensor(rng.normal(0.0, 0.02, (len(person.model), 3)), dtype=torch.float32))
    person.pose_offsets.requires_grad_(True)
    kernel_values, kernel_grads = posed_and_grads(person, degree, seed=5)
    monkeypatch.setattr(composite_cpu, "available", lambda: False)  # the PyTorch path
    values, grads = posed_and_grads(person, degree, seed=5)
    for name, value in values.items():
        torch.testing.assert_close(kernel_values[name], value, rtol=1e-4, atol=1e-5)
    assert set(kernel_grads) == set(grads)
    for name, grad in grads.items():
        rel = float((kernel_grads[name] - grad).norm() / grad.norm().clamp(min=1e-30))
        assert rel < GRAD_REL, f"{name}: relative L2 {rel:.2e}"
    assert grads["pose_offsets"].abs().sum() > 0 and grads["means"].abs().sum() > 0
