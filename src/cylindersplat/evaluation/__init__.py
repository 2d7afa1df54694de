"""Evaluation: methods (the model, baselines) rendered on dataset protocols, metrics, tables, pictures."""

from .evaluate import OCCLUDED_METRICS, EvalResult, evaluate, occluded_masks, score_views
from .fills import FILL_DESCRIPTIONS, FILLS, fill_uncovered, harmonic_inpaint, mean_input_colour
from .masked import MIN_OCCLUDED_PIXELS, masked_l1, masked_psnr, masked_ws_psnr
from .methods import Method, fill_methods, forward_warp_method, model_method, with_fill
from .table import METRIC_COLUMNS, OCCLUDED_COLUMNS, VIEW_COUNTS, results_to_markdown

__all__ = [name for name in dir() if not name.startswith("_")]
