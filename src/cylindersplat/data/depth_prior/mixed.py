"""A prior that is, per view, one of several priors (``mixed:gt+simulated``): training data whose depth is
sometimes exact and sometimes degraded, so that the model learns to leave good depth alone (issue 34).

The choice is seeded by the view's key (the same view always gets the same prior, so a run is reproducible and
an epoch sees every kind); ``mixed:A+B,seed=N`` changes the draw. Each part is any prior spec without a comma.
"""

from __future__ import annotations

import hashlib

from torch import Tensor

from .base import DepthPrior, PriorQuery

__all__ = ["MixedPrior"]


class MixedPrior(DepthPrior):
    """One of ``parts`` per view, chosen uniformly by a hash of ``(seed, key)``."""

    name = "mixed"

    def __init__(self, parts: tuple[DepthPrior, ...] = (), seed: int = 0) -> None:
        if len(parts) < 2:
            raise ValueError("a mixed prior needs at least two parts, e.g. mixed:gt+simulated")
        self.parts, self.seed = tuple(parts), int(seed)

    @staticmethod
    def spec_arguments(text: str) -> dict:
        """``A+B[+C...]`` or ``A+B,seed=N`` -> ``{"parts": (prior, ...), "seed": N}``."""
        from .degraded import seed_setting
        from .registry import parse_depth_prior

        names, _, rest = text.partition(",")
        arguments: dict = {"seed": seed_setting(rest, "mixed prior")}
        parts = [name for name in names.split("+") if name]
        if len(parts) < 2:
            raise ValueError("mixed prior: give at least two priors joined by '+', e.g. mixed:gt+simulated")
        if any(part.startswith("mixed") for part in parts):
            raise ValueError("mixed prior: a part cannot itself be mixed")
        try:
            arguments["parts"] = tuple(parse_depth_prior(part) for part in parts)
        except (ValueError, FileNotFoundError) as error:
            raise ValueError(f"mixed prior: {error}") from None
        return arguments

    def choice(self, key: str) -> DepthPrior:
        digest = hashlib.sha256(f"mixed:{self.seed}:{key}".encode()).digest()
        return self.parts[int.from_bytes(digest[:8], "little") % len(self.parts)]

    def source(self, query: PriorQuery) -> str:
        return self.choice(query.key).source(query)

    def __call__(self, query: PriorQuery) -> Tensor:
        return self.choice(query.key)(query)
