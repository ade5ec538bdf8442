"""The rasterizer: the C++ cpu backend against the pure-PyTorch reference, the reference
against finite differences and closed forms, tile binning against no binning, and the
pixel convention. gsplat (CUDA) is compared when a GPU is present."""


import pytest
import torch

from glimpse.render import Camera, RenderConfig, rasterize
from glimpse.render.binning import bin_gaussians
from glimpse.render.composite_cpu import available as cpu_available, composite_cpu
from glimpse.render.composite_torch import composite_dense, composite_torch
from glimpse.render.projection import LOW_PASS, project_gaussians, project_gaussians_cpu, quat_scale_to_covariance
from glimpse.render.sh import C0

needs_cpu_kernel = pytest.mark.skipif(not cpu_available(), reason="the C++ kernel does not build here")
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
IMAGE_ATOL = 1e-5
DEPTH_RTOL = 1e-5  # depth is in metres (about 4 here): float32 sums of many faint contributions round relative to it
GRAD_REL, GRAD_COS = 1e-4, 0.9999


def settings(backend: str, antialiased: bool = False) -> RenderConfig:
    return RenderConfig(backend=backend, sh_degree=3, antialiased=antialiased)


def camera(width=64, height=48, focal=55.0, dtype=torch.float32) -> Camera:
    K = torch.tensor([[focal, 0, (width - 1) / 2], [0, focal, (height - 1) / 2], [0, 0, 1]], dtype=dtype)
    return Camera(K, torch.eye(3, dtype=dtype), torch.zeros(3, dtype=dtype), width, height)


def turned_camera() -> Camera:
    """camera()'s intrinsics, turned and moved off the world's axes (every entry of R and t in play)."""
    R = torch.linalg.matrix_exp(torch.tensor([[0, -0.1, 0.2], [0.1, 0, -0.05], [-0.2, 0.05, 0]]))
    return Camera(camera().K, R, torch.tensor([0.1, -0.2, 0.3]), 64, 48)


def scene(kind: str, n: int = 400, seed: int = 0) -> dict:
    """Random Gaussians in front of the camera, plus the hard cases of `kind`."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([1.0, 0.8, 0.6]) + torch.tensor([0.0, 0.0, 4.0])
    params = {
        "means": means, "quats": torch.randn(n, 4, generator=g),
        "scales": torch.rand(n, 3, generator=g) * 0.12 + 0.01,
        "opacities": torch.rand(n, generator=g) * 0.9 + 0.05, "colors": torch.rand(n, 3, generator=g),
    }
    if kind == "behind":  # a third behind the camera or closer than the near plane
        params["means"][: n // 3, 2] = -params["means"][: n // 3, 2].abs() + 0.005
    elif kind == "border":  # straddling the image border and far outside it
        params["means"][: n // 2, 0] = 4.0 * 0.58 * torch.sign(params["means"][: n // 2, 0])
        params["means"][n // 2: n // 2 + 20, 1] = 30.0
    elif kind == "degenerate":  # needle- and disc-like, tiny and huge
        params["scales"][: n // 4, :2] = 1e-5
        params["scales"][n // 4: n // 2, 2] = 1e-6
        params["scales"][n // 2: n // 2 + 10] = 2.0
        params["opacities"][-20:] = 0.9999
    elif kind == "slanted":  # long thin Gaussians at every angle, a quarter so faint that alpha barely reaches 1/255
        params["scales"][:, 0] = torch.rand(n, generator=g) * 0.6 + 0.05
        params["scales"][:, 1:] = torch.rand(n, 2, generator=g) * 0.01 + 1e-4
        params["opacities"][: n // 4] = (1.0 + torch.rand(n // 4, generator=g) * 0.05) / 255.0
    return params


def render_with_grads(backend: str, params: dict, cam: Camera, covariance_input: bool = False,
                      antialiased: bool = False):
    leaves = {k: v.clone().requires_grad_(True) for k, v in params.items()}
    geometry = ({"covariances": quat_scale_to_covariance(leaves["quats"], leaves["scales"])} if covariance_input
                else {"quats": leaves["quats"], "scales": leaves["scales"]})
    device = params["means"].device
    groups = torch.arange(len(params["means"]), device=device) % 3
    out = rasterize(cam, means=leaves["means"], opacities=leaves["opacities"], colors=leaves["colors"],
                    background=torch.tensor([0.1, 0.5, 0.9], device=device), groups=groups, num_groups=3,
                    settings=settings(backend, antialiased), **geometry)
    g = torch.Generator().manual_seed(7)  # the same random cotangents for both backends (drawn on the CPU)

    def cotangent(shape: torch.Size) -> torch.Tensor:
        return torch.rand(shape, generator=g).to(device)

    loss = ((out.rgb * cotangent(out.rgb.shape)).sum() + (out.alpha * cotangent(out.alpha.shape)).sum()
            + (out.group_alpha[1] * cotangent(out.alpha.shape)).sum() + 0.1 * out.depth.sum())
    loss.backward()
    return out, {k: v.grad for k, v in leaves.items()}


def assert_grad_close(reference: torch.Tensor, other: torch.Tensor, name: str) -> None:
    rel = float((reference - other).norm() / reference.norm().clamp(min=1e-30))
    cos = float(torch.nn.functional.cosine_similarity(reference.flatten(), other.flatten(), dim=0))
    assert rel < GRAD_REL and cos > GRAD_COS, f"{name}: relative L2 {rel:.2e}, cosine {cos:.8f}"


def assert_cpu_matches_the_reference(params: dict, cam: Camera, covariance_input: bool, antialiased: bool) -> None:
    ref, ref_grads = render_with_grads("torch", params, cam, covariance_input, antialiased=antialiased)
    out, grads = render_with_grads("cpu", params, cam, covariance_input, antialiased=antialiased)
    for name in ("rgb", "alpha", "group_alpha"):
        torch.testing.assert_close(getattr(out, name), getattr(ref, name), rtol=0, atol=IMAGE_ATOL)
    torch.testing.assert_close(out.depth, ref.depth, rtol=DEPTH_RTOL, atol=IMAGE_ATOL)
    assert ref.alpha.max() > 0.5  # the scene draws something
    for name in params:
        assert_grad_close(ref_grads[name], grads[name], name)
    assert torch.equal(out.radii, ref.radii)


@needs_cpu_kernel
@pytest.mark.parametrize("kind", ["random", "behind", "border", "degenerate"])
@pytest.mark.parametrize("covariance_input", [False, True])
@pytest.mark.parametrize("antialiased", [False, True])
def test_cpu_backend_matches_the_torch_reference(kind, covariance_input, antialiased):
    assert_cpu_matches_the_reference(scene(kind), camera(), covariance_input, antialiased)


@needs_cpu_kernel
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_slanted_and_faint_gaussians_match_the_torch_reference(seed):
    """The C++ compositor walks only the lane groups of a box that each row's ellipse reaches: long thin Gaussians
    at every angle, a quarter of them so faint that alpha barely reaches 1/255, lose no pixel. (Not antialiased:
    there such needles' compensated opacities fall within rounding of 1/255, where the two backends' float32
    projections decide differently, with or without the walk's spans.)"""
    assert_cpu_matches_the_reference(scene("slanted", seed=seed), camera(), seed == 1, antialiased=False)


@needs_cpu_kernel
def test_cpu_projection_backward_with_outputs_the_loss_does_not_read():
    """A loss on the screen positions alone leaves the other outputs without a gradient (None in the backward):
    the kernel's gradients are still the autograd projection's."""
    params, cam = scene("random"), camera()
    grads = []
    for project in (project_gaussians, project_gaussians_cpu):
        means = params["means"].clone().requires_grad_(True)
        covariances = quat_scale_to_covariance(params["quats"], params["scales"]).detach().requires_grad_(True)
        p = project(means, covariances, params["opacities"], cam)
        (p.means2d[p.visible] * torch.tensor([1.0, -2.0])).sum().backward()
        grads.append((means.grad, covariances.grad))
    (ref_means, ref_cov), (means_g, cov_g) = grads
    assert_grad_close(ref_means, means_g, "means")
    assert all(g is None or not g.any() for g in (ref_cov, cov_g))  # screen positions do not depend on them


@needs_cpu_kernel
@pytest.mark.parametrize("antialiased", [False, True])
def test_each_gaussian_projects_alike_alone_and_among_others(antialiased):
    """The covariance and projection kernels compute eight Gaussians at a time, one per vector lane, and fill the
    lanes of a last, partial group with copies. A Gaussian's outputs and gradients must depend on its own inputs
    alone: each of a mixed set (behind the camera, off the image, needles, ordinary ones) computed within the set of
    19 (two whole groups and a partial one) and alone (one lane used) gives the same to the bit."""
    g = torch.Generator().manual_seed(5)
    parts = [scene(kind, n=40, seed=2) for kind in ("behind", "border", "degenerate", "random")]
    pick = torch.randperm(160, generator=g)[:19]
    params = {k: torch.cat([part[k] for part in parts])[pick] for k in ("means", "quats", "scales", "opacities")}
    weights = {name: torch.randn(19, width, generator=g).squeeze(1)
               for name, width in (("means2d", 2), ("conics", 3), ("depths", 1), ("opacities", 1))}
    cam = turned_camera()

    def project(rows: slice) -> list[torch.Tensor]:
        leaves = {k: v[rows].clone().requires_grad_(True) for k, v in params.items()}
        p = project_gaussians_cpu(leaves["means"], quat_scale_to_covariance(leaves["quats"], leaves["scales"]),
                                  leaves["opacities"], cam, antialiased)
        sum((getattr(p, name) * w[rows]).sum() for name, w in weights.items()).backward()
        outputs = (p.means2d, p.conics, p.depths, p.opacities, p.extents, p.radii, p.visible)
        return [t.detach() for t in outputs] + [leaves[k].grad for k in params]

    together = project(slice(None))
    alone = [torch.cat(parts) for parts in zip(*(project(slice(i, i + 1)) for i in range(19)))]
    assert together[-4].abs().sum() > 0 and together[6].any() and not together[6].all()  # gradients; some culled
    for a, b in zip(together, alone):
        assert torch.equal(a, b)


@needs_cpu_kernel
@pytest.mark.parametrize("active", [1, 3, 4, 11])
def test_the_backward_matches_the_reference_for_any_number_of_active_channels(active):
    """The kernel's backward has walks compiled for 3 and 4 active channels (colour; colour over a background) and
    one for any other count, and sums each Gaussian's per-lane sums (6 + active of them) in groups of eight: 11
    active channels take three groups."""
    params, cam = scene("random"), camera()
    features = torch.rand(len(params["colors"]), active + 1, generator=torch.Generator().manual_seed(5))
    weights = torch.rand(active + 1, generator=torch.Generator().manual_seed(6)) + 0.5
    weights[0] = 0.0  # one channel without a gradient: the active ones are not the first ones
    grads = {}
    for backend in ("torch", "cpu"):
        leaves = {k: v.clone().requires_grad_(True) for k, v in params.items() if k != "colors"}
        leaves["features"] = features.clone().requires_grad_(True)
        p = project_gaussians(leaves["means"], quat_scale_to_covariance(leaves["quats"], leaves["scales"]),
                              leaves["opacities"], cam)
        bins = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, cam.width, cam.height, 16)
        composite = composite_cpu if backend == "cpu" else composite_torch
        args = (p.means2d, p.conics, p.opacities, leaves["features"])
        image = (composite(*args, p.extents, bins, cam.width, cam.height) if backend == "cpu"
                 else composite(*args, bins, cam.width, cam.height))
        (image * weights).sum().backward()
        grads[backend] = {k: v.grad for k, v in leaves.items()}
    for name, reference in grads["torch"].items():
        assert_grad_close(reference, grads["cpu"][name], name)
    assert torch.equal(grads["cpu"]["features"][:, 0], torch.zeros(len(features)))


@needs_cpu_kernel
def test_a_loss_on_colour_alone_gets_the_reference_gradients():
    """The kernel's backward skips channels whose gradient is zero everywhere (here red and two extra channels, as
    alpha and depth are when a loss reads colour alone): the gradients are still the reference's, and zero for
    the skipped channels' features."""
    params, cam = scene("random"), camera()
    extra = torch.rand(len(params["colors"]), 2, generator=torch.Generator().manual_seed(3))  # both backends alike
    grads = {}
    for backend in ("torch", "cpu"):
        leaves = {k: v.clone().requires_grad_(True) for k, v in params.items()}
        features = torch.cat([leaves["colors"], extra], 1)
        p = project_gaussians(leaves["means"], quat_scale_to_covariance(leaves["quats"], leaves["scales"]),
                              leaves["opacities"], cam)
        bins = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, cam.width, cam.height, 16)
        if backend == "cpu":
            image = composite_cpu(p.means2d, p.conics, p.opacities, features, p.extents, bins, cam.width, cam.height)
        else:
            image = composite_torch(p.means2d, p.conics, p.opacities, features, bins, cam.width, cam.height)
        features.retain_grad()
        (image[..., :3] * torch.linspace(0, 1, 3)).sum().backward()  # red's weight is 0: channels 1 and 2 active
        grads[backend] = {**{k: v.grad for k, v in leaves.items()}, "extra features": features.grad[:, 3:]}
    for name, reference in grads["torch"].items():
        if name == "extra features":
            assert torch.equal(grads["cpu"][name], torch.zeros_like(reference)) and not reference.any()
        else:
            assert_grad_close(reference, grads["cpu"][name], name)


@needs_cpu_kernel
@pytest.mark.parametrize("kind", ["random", "behind", "border", "degenerate"])
@pytest.mark.parametrize("antialiased", [False, True])
def test_cpu_projection_matches_the_autograd_projection(kind, antialiased):
    params = scene(kind, n=403)  # not a multiple of the kernel's 8 lanes: each thread's last group is partial
    cam = turned_camera()
    results = []
    for project in (project_gaussians, project_gaussians_cpu):
        means, opacities = params["means"].clone().requires_grad_(True), params["opacities"].clone().requires_grad_(True)
        covariances = quat_scale_to_covariance(params["quats"], params["scales"]).detach().requires_grad_(True)
        p = project(means, covariances, opacities, cam, antialiased)
        g = torch.Generator().manual_seed(1)
        keep = p.visible[:, None].float()  # culled Gaussians never reach the compositor
        loss = sum((t * keep[:, : t.shape[1]] if t.ndim == 2 else t * keep[:, 0]).mul(torch.randn(t.shape, generator=g)).sum()
                   for t in (p.means2d, p.conics, p.depths, p.opacities))
        loss.backward()
        results.append((p, means.grad, covariances.grad, opacities.grad))
    (ref, *ref_grads), (out, *grads) = results
    assert torch.equal(ref.visible, out.visible) and torch.equal(ref.radii, out.radii)
    v = ref.visible
    for name in ("means2d", "conics", "depths", "opacities"):
        torch.testing.assert_close(getattr(out, name)[v], getattr(ref, name)[v], rtol=1e-5, atol=1e-5)
    # extents follow log(opacity); Mip-Splatting's compensation of a nearly flat Gaussian cancels
    # catastrophically in float32, so they agree to 1e-3 there (binning has 1e-3 slack for this)
    torch.testing.assert_close(out.extents[v], ref.extents[v], rtol=1e-3, atol=1e-5)
    # A covariance is symmetric: only the symmetric part of its gradient reaches whatever produced
    # it (R S Sᵀ Rᵀ, A Σ Aᵀ). Autograd's raw gradient is not symmetric; the kernel returns the symmetric one.
    ref_means, ref_cov, ref_opac = ref_grads
    means_g, cov_g, opac_g = grads
    assert_grad_close(ref_means, means_g, "means")
    assert_grad_close(0.5 * (ref_cov + ref_cov.transpose(1, 2)), cov_g, "covariances")
    torch.testing.assert_close(cov_g, cov_g.transpose(1, 2), rtol=1e-5, atol=1e-5)
    assert_grad_close(ref_opac, opac_g, "opacities")


def test_binning_loses_nothing():
    """Per-tile compositing equals compositing every pixel against every Gaussian."""
    for kind in ("random", "border", "degenerate"):
        params, cam = scene(kind, n=150), camera(40, 30)
        p = project_gaussians(params["means"], quat_scale_to_covariance(params["quats"], params["scales"]),
                              params["opacities"], cam)
        bins = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, cam.width, cam.height, 16)
        tiled = composite_torch(p.means2d, p.conics, p.opacities, params["colors"], bins, cam.width, cam.height)
        dense = composite_dense(p.means2d, p.conics, p.opacities, params["colors"], p.depths, p.visible,
                                cam.width, cam.height)
        torch.testing.assert_close(tiled, dense, rtol=0, atol=1e-6)


@needs_cpu_kernel
@pytest.mark.parametrize("threads", [1, 2, 3])
def test_cpu_binning_equals_torch_binning(threads):
    """The C++ binning shares its work among threads; every thread count gives the serial lists."""
    params, cam = scene("border", n=500), camera(70, 50)
    p = project_gaussians(params["means"], quat_scale_to_covariance(params["quats"], params["scales"]),
                          params["opacities"], cam)
    p.depths[::7] = p.depths[3]  # ties broken by index in both
    a = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, cam.width, cam.height, 16, use_cpu_kernel=False)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        b = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, cam.width, cam.height, 16, use_cpu_kernel=True)
    finally:
        torch.set_num_threads(before)
    assert torch.equal(a.gaussian_ids, b.gaussian_ids) and torch.equal(a.tile_offsets, b.tile_offsets)


def test_torch_reference_gradients_match_finite_differences():
    torch.manual_seed(3)
    cam = camera(12, 10, focal=10.0, dtype=torch.float64)
    n = 5
    means = (torch.randn(n, 3, dtype=torch.float64) * 0.3 + torch.tensor([0.0, 0.0, 3.0], dtype=torch.float64))
    quats = torch.randn(n, 4, dtype=torch.float64)
    scales = torch.rand(n, 3, dtype=torch.float64) * 0.3 + 0.2
    opacities = torch.rand(n, dtype=torch.float64) * 0.5 + 0.3
    colors = torch.rand(n, 3, dtype=torch.float64)

    def image(means, quats, scales, opacities, colors):
        out = rasterize(cam, means=means, quats=quats, scales=scales, opacities=opacities, colors=colors,
                        background=torch.tensor([0.3, 0.2, 0.1], dtype=torch.float64), settings=settings("torch"))
        return out.rgb

    inputs = [t.requires_grad_(True) for t in (means, quats, scales, opacities, colors)]
    assert torch.autograd.gradcheck(image, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


@pytest.mark.parametrize("backend", ["torch", pytest.param("cpu", marks=needs_cpu_kernel)])
def test_a_single_gaussian_has_the_closed_form_image(backend):
    """An isotropic Gaussian on the optical axis: alpha(u, v) = o exp(-d²/(2 s²)), s² = (f σ/z)² + 0.3,
    centred on the principal point (OpenCV pixel convention: the centre of pixel (u, v) is (u, v))."""
    cam = camera(33, 25, focal=40.0)
    sigma, z, o = 0.05, 2.0, 0.8
    out = rasterize(cam, means=torch.tensor([[0.0, 0.0, z]]), quats=torch.tensor([[1.0, 0, 0, 0]]),
                    scales=torch.full((1, 3), sigma), opacities=torch.tensor([o]), colors=torch.ones(1, 3),
                    settings=settings(backend))
    s2 = (40.0 * sigma / z) ** 2 + LOW_PASS
    v, u = torch.meshgrid(torch.arange(25.0), torch.arange(33.0), indexing="ij")
    expected = o * torch.exp(-((u - 16.0) ** 2 + (v - 12.0) ** 2) / (2 * s2))
    expected = torch.where(expected >= 1 / 255, expected, torch.zeros_like(expected))
    torch.testing.assert_close(out.alpha, expected, rtol=0, atol=2e-6)
    assert out.alpha.argmax() == 12 * 33 + 16
    torch.testing.assert_close(out.depth[12, 16], torch.tensor(z))


@pytest.mark.parametrize("backend", ["torch", pytest.param("cpu", marks=needs_cpu_kernel)])
def test_a_projected_point_lands_on_its_pixel(backend):
    cam = camera(50, 40, focal=45.0)
    cam = Camera(cam.K, torch.tensor([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]), torch.tensor([0.2, -0.1, 3.0]), 50, 40)
    for u, v in ((7, 31), (42, 5)):
        ray = torch.linalg.solve(cam.K, torch.tensor([u, v, 1.0])) * 2.5  # camera frame point at depth 2.5
        world = cam.R.T @ (ray - cam.t)
        out = rasterize(cam, means=world[None], quats=torch.tensor([[1.0, 0, 0, 0]]), scales=torch.full((1, 3), 0.01),
                        opacities=torch.tensor([0.9]), colors=torch.ones(1, 3), settings=settings(backend))
        assert divmod(int(out.alpha.argmax()), 50) == (v, u)
        assert out.alpha[v, u - 1] == pytest.approx(float(out.alpha[v, u + 1]), abs=1e-5)  # float32 round trip


def test_groups_background_sh_and_screen_gradients():
    params, cam = scene("random", n=200), camera()
    sh = torch.zeros(200, 9, 3)
    sh[:, 0] = (params["colors"] - 0.5) / C0  # DC only: the same colour from every direction
    background = torch.tensor([0.2, 0.4, 0.6])
    a = rasterize(cam, means=params["means"], quats=params["quats"], scales=params["scales"],
                  opacities=params["opacities"], colors=params["colors"], background=background,
                  groups=torch.arange(200) % 4, num_groups=4, settings=settings("torch"))
    b = rasterize(cam, means=params["means"], quats=params["quats"], scales=params["scales"],
                  opacities=params["opacities"], sh=sh, background=background, settings=settings("torch"))
    torch.testing.assert_close(a.rgb, b.rgb, rtol=0, atol=1e-6)
    torch.testing.assert_close(a.group_alpha.sum(0), a.alpha, rtol=0, atol=1e-6)
    none = rasterize(cam, means=params["means"][:0], quats=params["quats"][:0], scales=params["scales"][:0],
                     opacities=params["opacities"][:0], colors=params["colors"][:0], background=background,
                     settings=settings("torch"))
    torch.testing.assert_close(none.rgb, background.expand(48, 64, 3))
    means = params["means"].clone().requires_grad_(True)
    out = rasterize(cam, means=means, quats=params["quats"], scales=params["scales"], opacities=params["opacities"],
                    colors=params["colors"], settings=settings("torch"))
    out.means2d.retain_grad()
    out.rgb.sum().backward()
    assert out.means2d.grad is not None and (out.means2d.grad[out.visible].abs().sum(1) > 0).float().mean() > 0.5
    assert ((out.radii > 0) == out.visible).all()


def test_hidden_gaussians_are_culled():
    params = scene("behind", n=90)
    out = rasterize(camera(), means=params["means"], quats=params["quats"], scales=params["scales"],
                    opacities=params["opacities"], colors=params["colors"], settings=settings("torch"))
    assert not out.visible[:30].any() and (out.radii[:30] == 0).all()


@needs_cuda
def test_gsplat_matches_the_cpu_backend():
    params, cam = scene("random"), camera()
    cpu, cpu_grads = render_with_grads("cpu" if cpu_available() else "torch", params, cam)
    cuda_params = {k: v.cuda() for k, v in params.items()}
    cuda_cam = Camera(cam.K.cuda(), cam.R.cuda(), cam.t.cuda(), cam.width, cam.height)
    gpu, gpu_grads = render_with_grads("gsplat", cuda_params, cuda_cam)
    torch.testing.assert_close(gpu.rgb.cpu(), cpu.rgb, rtol=0, atol=1e-3)
    for name in params:
        assert_grad_close(cpu_grads[name], gpu_grads[name].cpu(), name)
