"""The pose wing's registry (cylindersplat.data.poses.registry): every ``--from`` name has a module with a
convention-table header and a reader, and the command line offers exactly the registry's names."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import cylindersplat.data.poses as poses
from cylindersplat.cli import build_parser
from cylindersplat.data.poses.conventions import PoseRecord
from cylindersplat.data.poses.registry import POSE_FORMATS, pose_format

HEADER_ROWS = ("Pose", "Panorama pixels", "To ours")  # what each reader's header table must say


@pytest.mark.parametrize("name", sorted(POSE_FORMATS))
def test_every_registry_entry_has_a_module_with_a_header_and_a_reader(name):
    entry = POSE_FORMATS[name]
    module = importlib.import_module(f"cylindersplat.data.poses.{entry.module}")
    header = module.__doc__ or ""
    assert header.count("=====") >= 2, f"{module.__name__}: its docstring opens with no convention table"
    for row in HEADER_ROWS:
        assert f"\n{row} " in header, f"{module.__name__}: its convention table has no {row!r} row"
    reader = getattr(module, entry.reader)
    assert callable(reader)
    parameters = list(inspect.signature(reader).parameters)
    assert parameters[:2] == ["path", "scale"], f"{entry.reader} must take (path, scale, ...)"
    assert set(entry.options) <= set(parameters[2:])
    assert entry.images in ("named", "relative", "ordered")
    assert entry.reader in module.__all__ and entry.reader in poses.__all__


def test_every_reader_module_is_registered():
    """A module of the package with a ``read_*`` function is a format and must have its registry line."""
    registered = {(e.module, e.reader) for e in POSE_FORMATS.values()}
    for info in pkgutil.iter_modules(poses.__path__):
        module = importlib.import_module(f"cylindersplat.data.poses.{info.name}")
        for name, value in vars(module).items():
            if name.startswith("read_") and inspect.isfunction(value) and value.__module__ == module.__name__ \
                    and inspect.signature(value).return_annotation in ("list[PoseRecord]", list[PoseRecord]):
                assert (info.name, name) in registered, f"{info.name}.{name} reads poses but has no registry line"


def test_import_poses_offers_exactly_the_registry():
    parser = build_parser()
    data = next(a for a in parser._subparsers._group_actions[0].choices["data"]._actions
                if a.dest == "data_command")
    action = next(a for a in data.choices["import-poses"]._actions if a.dest == "source_format")
    assert tuple(action.choices) == tuple(POSE_FORMATS)


def test_unknown_format_is_one_line():
    with pytest.raises(ValueError, match="unknown pose format 'ply'; use one of opensfm, nerfstudio"):
        pose_format("ply")
