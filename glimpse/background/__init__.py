"""Stage 04: background Gaussians pre-trained on the pixels no person covers (paper supplementary,
"Background pre-optimization"): initialisation (SfM points or a textured sphere), the training loop,
never-seen regions, renders and the report."""
