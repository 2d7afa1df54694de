"""Evaluation metrics (batched torch): WS-PSNR, PSNR, SSIM, LPIPS, depth metrics, LRCE."""

from .depth import DepthRange, abs_rel, delta1, depth_metrics, lrce, pcc, rmse, valid_depth_mask
from .image import check_image_pair, psnr, ssim, ws_psnr, ws_weights
from .lpips import (
                    LPIPS,
                    LPIPS_WEIGHTS_ENV,
                    load_lpips,
                    lpips,
                    lpips_package_weights,
                    lpips_weights_available,
                    torchvision_vgg16_weights,
)

__all__ = [name for name in dir() if not name.startswith("_")]
