"""The variant catalogue as data: ``configs/studies/ablation_variants.yaml`` (the ablation's variants and named
change sets) and ``configs/recipes/*.yaml`` (earlier recipes of a preset, as change sets on it).

Changes are typed values under dotted keys (``model.volume.grid: [8, 32, 16]``); a :class:`~.schedule.Variant`
carries them as the ``key=value`` overrides a run's config is loaded with and its report records, written the
way the command line spells them (``model.volume.grid=[8,32,16]``).
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

import yaml

from .schedule import Variant

__all__ = ["CATALOGUE", "RECIPES", "override_text", "change_set", "recipe", "default_variants", "extra_variants",
           "all_variants", "variant_names", "pinned_to_earlier_tiny"]

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CATALOGUE = CONFIGS / "studies" / "ablation_variants.yaml"
RECIPES = CONFIGS / "recipes"
EARLIER_TINY = "tiny_earlier"  # the recipe the studies run before 2026-11-26 pin (configs/recipes/tiny_earlier.yaml)


def override_text(key: str, value: Any) -> str:
    """``key=value`` as the command line writes it: lists without spaces, booleans lower case."""

    def text(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (list, tuple)):
            return "[" + ",".join(text(x) for x in v) + "]"
        return str(v)

    return f"{key}={text(value)}"


def _overrides(changes: dict[str, Any] | None, where: str) -> tuple[str, ...]:
    if not isinstance(changes or {}, dict):
        raise ValueError(f"{where}: changes must be a mapping of dotted keys to values")
    return tuple(override_text(key, value) for key, value in (changes or {}).items())


@cache
def _read(path: Path) -> dict:
    data = yaml.safe_load(path.read_text()) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: top level must be a mapping")
    return data


def recipe(name: str) -> tuple[str, ...]:
    """The overrides of ``configs/recipes/NAME.yaml`` (a change set on its ``base`` preset)."""
    path = RECIPES / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in RECIPES.glob("*.yaml"))
        raise ValueError(f"unknown recipe {name!r}; configs/recipes/ has {', '.join(known)}")
    return _overrides(_read(path).get("changes"), str(path))


def change_set(name: str) -> tuple[str, ...]:
    """The overrides of a named change set: one of the catalogue's ``change_sets`` or a recipe."""
    sets = _read(CATALOGUE).get("change_sets") or {}
    if name in sets:
        return _overrides(sets[name], f"{CATALOGUE} change_sets.{name}")
    return recipe(name)


def _variant(entry: dict) -> Variant:
    where = f"{CATALOGUE} variant {entry.get('name')!r}"
    unknown = set(entry) - {"name", "description", "kind", "base", "changes"}
    if unknown or "name" not in entry:
        raise ValueError(f"{where}: expected name, description, kind, base, changes; got {sorted(map(str, entry))}")
    overrides = tuple(o for name in entry.get("base") or () for o in change_set(name))
    overrides += _overrides(entry.get("changes"), where)
    return Variant(entry["name"], entry.get("description", ""), overrides, entry.get("kind", "full"))


def default_variants() -> list[Variant]:
    """The paper's ablation rows (and the switches issue 11 asks for), in table order."""
    return [_variant(entry) for entry in _read(CATALOGUE)["default"]]


def extra_variants() -> list[Variant]:
    """Named variants outside the default study (it must fit 75 minutes on a 2-core CPU); run them with
    ``cylindersplat ablate --variants NAME ...``."""
    return [_variant(entry) for entry in _read(CATALOGUE)["extra"]]


def all_variants() -> list[Variant]:
    return default_variants() + extra_variants()


def variant_names() -> tuple[str, ...]:
    return tuple(v.name for v in all_variants())


def pinned_to_earlier_tiny(variants: list[Variant]) -> list[Variant]:
    """``variants`` with the earlier tiny recipe's overrides before their own switches (theirs win)."""
    from dataclasses import replace

    return [replace(v, overrides=recipe(EARLIER_TINY) + v.overrides) for v in variants]
