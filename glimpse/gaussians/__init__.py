"""3D Gaussian splats: the raw parameters (:class:`~glimpse.gaussians.ply.GaussianSplats`)
and their file format, the standard 3DGS PLY layout that INRIA's reference code,
gsplat and viewers such as SuperSplat read (:mod:`glimpse.gaussians.ply`)."""
