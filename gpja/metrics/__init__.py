"""Scores shared by every method: geometry (Chamfer, normal consistency, F-score), photometry (PSNR, SSIM, LPIPS), correspondence."""
