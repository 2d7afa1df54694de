"""The Triton backend's variants in the benchmarks (issue 35): their names on the command line
(``FORWARD[,OPTION...]``), switching them for a while, and their agreement with each other at the timed size.
The switches themselves are :data:`cylindersplat.render.triton_backend.VARIANT_FIELDS`."""

from __future__ import annotations

import argparse
import contextlib
import sys
import traceback

import torch

from cylindersplat.render import render, triton_backend
from cylindersplat.scenes import random_indoor

from .views import view_camera

__all__ = ["triton_variant_name", "triton_variant", "variant_agreement", "graphed_render", "graph_failure",
           "graph_variants", "GRAPH_ROW"]

GRAPH_ROW = "graph"  # the row name's tag of renders replayed as CUDA graphs (``--graph``)


def triton_variant_name(text: str) -> tuple[str, ...]:
    """``"FORWARD[,OPTION...]"`` (argparse type): a Triton forward (:data:`.triton_backend.FORWARDS`) and at most one
    value of each other switch of :data:`.triton_backend.VARIANT_FIELDS` (COMPACTION, CHECK, PAIR_FIELD,
    LOOKAHEAD), in any
    order: the forward, then the options that are not their switch's default, in the switches' order (every
    spelling of one variant has one name: its row's)."""
    forward, *options = text.split(",")
    fields = triton_backend.VARIANT_FIELDS
    usage = ("FORWARD[,OPTION...] with FORWARD one of " + ", ".join(triton_backend.FORWARDS) + " and OPTIONs from "
             + "; ".join(f"{name} one of {', '.join(values)}" for name, values in fields.items() if name != "FORWARD"))
    if forward not in triton_backend.FORWARDS:
        raise argparse.ArgumentTypeError(f"{text!r}: {forward!r} is not a forward; use {usage}")
    chosen: dict[str, str] = {}
    for option in options:
        field = next((name for name, values in fields.items() if name != "FORWARD" and option in values), None)
        if field is None:
            raise argparse.ArgumentTypeError(f"{text!r}: {option!r} is not an option; use {usage}")
        if field in chosen:
            raise argparse.ArgumentTypeError(f"{text!r} gives {field} twice ({chosen[field]}, {option}); use {usage}")
        chosen[field] = option
    return (forward,) + tuple(chosen[name] for name, values in fields.items()
                              if name in chosen and chosen[name] != values[0])


def graphed_render(gaussians, c2w: torch.Tensor, camera):
    """``render(gaussians, c2w, camera, backend="triton")`` replayed by :class:`cylindersplat.render.graphs.
    RenderGraph` (CUDA only): one graph without gradients, used under ``torch.no_grad``, and one with the backward,
    used otherwise, each captured at its first call (the benchmarks' warm-up call); ``.graphs`` holds them by
    ``backward``."""
    from cylindersplat.render.graphs import RenderGraph

    made = {}

    def run():
        backward = torch.is_grad_enabled()
        if backward not in made:
            made[backward] = RenderGraph(gaussians, c2w, camera, backward=backward)
        return made[backward](gaussians, c2w)

    run.graphs = made
    return run


def graph_variants(variants: list[tuple[str, ...]]) -> list[tuple[str, tuple[str, ...] | None]]:
    """``(row tag, variant)`` of the graph rows for the timed ``variants``: one per distinct set of options (a graph
    always captures the lean forward, every pair projected: the forward and the compaction are not the variant's),
    tagged ``graph`` and the options, e.g. ``graph,rects,id``; no variants: the defaults, ``graph``."""
    rows: dict[str, tuple[str, ...] | None] = {}
    for variant in variants or [None]:
        options = () if variant is None else tuple(o for o in variant[1:] if o not in triton_backend.COMPACTIONS)
        rows.setdefault(",".join((GRAPH_ROW, *options)), ("lean", *options) if variant else None)
    return list(rows.items())


def graph_failure(exc: BaseException) -> str:
    """A graph row's error cell for ``exc`` (its traceback printed to stderr for the log): the row fails, the
    benchmark goes on."""
    traceback.print_exception(exc, file=sys.stderr)
    first = (str(exc).strip().splitlines() or [""])[0]
    return f"graph failed: {type(exc).__name__}: {first[:300]}"


@contextlib.contextmanager
def triton_variant(forward: str | None = None, *options: str):
    """The Triton backend with the given forward (None: the current one) and options (values of the other switches
    of :data:`.triton_backend.VARIANT_FIELDS`, e.g. ``"nonzero"``, ``"ids"``; the rest stay) while inside."""
    fields = triton_backend.VARIANT_FIELDS
    saved = {name: getattr(triton_backend, name) for name in fields}
    try:
        if forward is not None:
            triton_backend.FORWARD = forward
        for option in options:
            if option is not None:
                setattr(triton_backend, next(name for name, values in fields.items() if option in values), option)
        yield
    finally:
        for name, value in saved.items():
            setattr(triton_backend, name, value)


def variant_agreement(num: int, height: int, device: torch.device, variants: list[tuple[str, ...]],
                      camera: str = "equirect") -> list[str]:
    """``# agreement`` lines: each Triton variant's image and gradients against the first variant's, on the
    benchmark's scene (the tests check them on small scenes; this, at the timed size)."""
    g = random_indoor(num).to(device)
    c2w = torch.eye(4, device=device)
    model = view_camera(camera, height)
    results = []
    for variant in variants:
        params = {k: v.detach().clone().requires_grad_() for k, v in g.tensors().items()}
        with triton_variant(*variant):
            try:
                out = render(type(g)(**params), c2w, model, backend="triton")
                weights = torch.linspace(-1.0, 1.0, out.rgb.numel(), device=device).view_as(out.rgb)
                grads = torch.autograd.grad((weights * out.rgb).sum() + out.depth.sum(), list(params.values()),
                                            allow_unused=True)
            except (torch.OutOfMemoryError, MemoryError):
                results.append(None)
                continue
        results.append((out.rgb.detach(), dict(zip(params, grads))))
        del out
    lines = []
    base, name0 = results[0], f"triton[{','.join(variants[0])}]"
    for variant, res in zip(variants[1:], results[1:]):
        head = f"# agreement triton[{','.join(variant)}] vs {name0} ({num} Gaussians): "
        if base is None or res is None:
            lines.append(head + "out of memory")
            continue
        rel = {k: float((res[1][k] - v).abs().max() / v.abs().max().clamp_min(1e-12))
               for k, v in base[1].items() if v is not None and res[1][k] is not None}
        lines.append(head + f"rgb max |diff| {float((res[0] - base[0]).abs().max()):.2e}, gradients max |diff| / "
                     "max |grad|: " + ", ".join(f"{k} {v:.1e}" for k, v in rel.items()))
    return lines
