"""Evaluation: methods (the model, baselines) rendered on dataset protocols, metrics, tables, pictures."""

from .evaluate import EvalResult, evaluate
from .methods import Method, forward_warp_method, model_method
from .table import METRIC_COLUMNS, results_to_markdown

__all__ = [name for name in dir() if not name.startswith("_")]
