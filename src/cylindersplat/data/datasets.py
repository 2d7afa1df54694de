"""One registry of dataset layouts and the choices around them, shared by ``train`` and ``eval``.

:data:`DATASETS` maps a layout name (``data.format`` / ``eval --format``) to its loader, the ``open`` of its
:class:`~cylindersplat.dataset_layouts.DatasetSpec` in the registry.
:func:`make_dataset` opens one with the three depth choices kept apart:

* the model's **input prior** (``data.depth_prior``): ``default`` (the dataset's own: the
  simulated prior for synthetic data, the depth files of a folder of panoramas, an error asking
  for a choice elsewhere), ``file:NAME``,
  ``simulated``, ``gt``, ``constant:M``, ``none`` or a network spec (``unik3d:DIR``, ...);
* a **reference depth of the targets** (``loss.depth_reference`` for training, ``--pcc-reference``
  for evaluation): ``gt`` (the dataset's ground truth, ``Sample.target_depths``), ``prior`` (the
  input prior computed for the target views), ``file:NAME`` or ``none``; ``prior`` and ``file:``
  fill ``Sample.target_reference_depths``.

Everything that can be checked before the first step is checked here (one line each): a dataset
without a prior of its own and no choice, prior files that are missing (naming
``cylindersplat data priors``), a ``gt`` reference on data without ground-truth depth.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Callable

from ..dataset_layouts import DATASET_SPECS, dataset_spec, layout_name
from .base import FrameRef, PanoramaDataset
from .depth_prior import FilePrior, MissingPrior, NoPrior, StoredDepthPrior, parse_depth_prior, require_depth_prior

__all__ = ["DATASETS", "REFERENCES", "make_dataset", "check_reference_spec", "attach_reference", "check_prior_files"]


class _Loaders(Mapping):
    """layout name -> its spec's loader, ``open(root, *, views, split, resolution, depth_prior, **layout options)``:
    a view of the registry (:data:`cylindersplat.dataset_layouts.DATASET_SPECS`), layouts added later included."""

    def __getitem__(self, name: str) -> Callable[..., PanoramaDataset]:
        if name not in DATASET_SPECS:
            raise KeyError(name)
        return dataset_spec(name).open

    def __iter__(self) -> Iterator[str]:
        return iter(list(DATASET_SPECS))

    def __len__(self) -> int:
        return len(DATASET_SPECS)


DATASETS: Mapping[str, Callable[..., PanoramaDataset]] = _Loaders()

REFERENCES = ("gt", "prior", "none", "file:NAME")


def check_reference_spec(spec: str, option: str, allowed: tuple[str, ...] = ("gt", "prior", "none")) -> str:
    """``spec`` if it is one of ``allowed`` or ``file:NAME``; else a one-line ``ValueError``."""
    if spec in allowed or (spec.startswith("file:") and len(spec) > len("file:")):
        return spec
    raise ValueError(f"{option} must be one of {', '.join(allowed)} or file:NAME, got {spec!r}")


def _frames_by_role(dataset: PanoramaDataset) -> tuple[list[FrameRef], list[FrameRef]]:
    """The frames used as contexts and as targets over all examples (each once)."""
    context: dict[Path, FrameRef] = {}
    target: dict[Path, FrameRef] = {}
    for index in range(len(dataset)):
        ref = dataset.example(index)
        for i in ref.views.context:
            context.setdefault(Path(ref.frames[i].rgb), ref.frames[i])
        for i in ref.views.target:
            target.setdefault(Path(ref.frames[i].rgb), ref.frames[i])
    return list(context.values()), list(target.values())


def check_prior_files(dataset: PanoramaDataset, prior, frames: list[FrameRef], option: str) -> None:
    """For a :class:`FilePrior`: every frame has its file, else ``FileNotFoundError`` naming ``data priors``
    (behind a :class:`StoredDepthPrior`: every frame without a depth file of its own)."""
    if isinstance(prior, StoredDepthPrior):
        prior, frames = prior.fallback, [f for f in frames if f.depth is None]
    if not isinstance(prior, FilePrior) or not frames:
        return
    missing = [f for f in frames if prior.find(f.rgb, dataset.data_root) is None]
    if missing:
        raise FileNotFoundError(f"{option}={prior.spec}: {len(missing)} of {len(frames)} panoramas have no prior file; "
                                + prior.missing_help(missing[0].rgb, dataset.data_root))


def attach_reference(dataset: PanoramaDataset, reference: str, option: str,
                     targets: list[FrameRef] | None = None) -> None:
    """Make ``dataset`` deliver the ``reference`` depth of its targets (see the module docstring), or fail now."""
    check_reference_spec(reference, option)
    if reference == "none":
        return
    if targets is None:
        targets = _frames_by_role(dataset)[1]
    if reference == "gt":
        lacking = [f for f in targets if f.depth is None]
        if lacking:
            raise ValueError(f"{option}=gt but {lacking[0].rgb} (and {len(lacking) - 1} more) has no ground-truth "
                             f"depth ({type(dataset).__name__}); choose {option}=prior (the input prior of the target "
                             f"views), {option}=file:NAME (files from `cylindersplat data priors`) or {option}=none")
        return
    if reference == "prior":
        prior = dataset.depth_prior
        if isinstance(prior, NoPrior):
            raise ValueError(f"{option}=prior but the input prior is none (zeros): choose another input prior, or "
                             f"{option}=gt / file:NAME / none")
        if isinstance(prior, StoredDepthPrior) and isinstance(prior.fallback, MissingPrior):
            lacking = [f for f in targets if f.depth is None]
            if lacking:
                raise ValueError(f"{option}=prior but {lacking[0].rgb} has no depth file and no input prior is chosen; "
                                 f"choose one, or {option}=file:NAME / none")
    else:
        prior = parse_depth_prior(reference)
    check_prior_files(dataset, prior, targets, option)
    dataset.target_reference = prior


def make_dataset(
    layout: str,
    root: str | Path,
    *,
    views: str = "two_view",
    split: str = "test",
    resolution: tuple[int, int] | None = None,
    depth_prior: str = "default",
    reference: str = "none",
    prior_option: str = "data.depth_prior",
    reference_option: str = "loss.depth_reference",
    check_plausibility: bool = True,
    **options,
) -> PanoramaDataset:
    """Open ``root`` as ``layout`` (a name of the dataset registry) with an input prior and a target reference.

    ``options`` go to the loader (``scenes=[...]`` for synthetic data, ``dist=`` for PanoGRF, ...);
    ``prior_option`` / ``reference_option`` name the settings in error messages. ``check_plausibility=False``
    reads frames outside the plausibility bounds (:meth:`~cylindersplat.data.base.PanoramaDataset.check_frame`).
    """
    layout = layout_name(layout)
    if not root:
        raise ValueError("no dataset folder given (data.root / --data), e.g. one from `cylindersplat data synth`")
    check_reference_spec(reference, reference_option)
    kwargs = dict(options)
    if resolution is not None:
        kwargs["resolution"] = tuple(resolution)
    if depth_prior != "default":
        kwargs["depth_prior"] = parse_depth_prior(depth_prior)  # a name or name:value, e.g. unik3d:/weights
    dataset = dataset_spec(layout).open(root, views=views, split=split, **kwargs)
    dataset.check_plausibility = check_plausibility
    require_depth_prior(dataset, prior_option)  # no silent zeros: the PanoGRF / 360Loc default asks for a choice
    check_depth = getattr(dataset, "check_depth", None)  # a layout whose frames may lack depth files (folders)
    if check_depth is not None:
        check_depth(prior_option)  # frames without a depth file need a chosen prior
    if isinstance(dataset.depth_prior, (FilePrior, StoredDepthPrior)) or reference != "none":
        contexts, targets = _frames_by_role(dataset)
        check_prior_files(dataset, dataset.depth_prior, contexts, prior_option)
        attach_reference(dataset, reference, reference_option, targets)
    return dataset
