"""The pose wing's registry (cylindersplat.data.poses.registry): every ``--from`` name has a module with a
convention-table header and a reader, and the command line offers exactly the registry's names."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from pathlib import Path

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


def test_the_worked_example_of_docs_poses_md_reads_poses(tmp_path):
    """docs/poses.md's new format (its module and registry line) works as the docs say."""
    import re
    import types

    import numpy as np

    from cylindersplat.data.poses.conventions import PoseFormat

    text = (Path(__file__).parents[1] / "docs" / "poses.md").read_text()
    module_code, registry_line = re.findall(r"```python\n(.*?)```", text, re.S)[:2]
    module = types.ModuleType("cylindersplat.data.poses.pano_csv", module_code.split('"""')[1])
    module.__package__ = "cylindersplat.data.poses"
    exec(compile(module_code, "docs/poses.md", "exec"), module.__dict__)
    entry = eval(registry_line.strip().rstrip(",").split(": ", 1)[1], {"PoseFormat": PoseFormat})
    assert entry.module == "pano_csv" and callable(getattr(module, entry.reader))
    for row in HEADER_ROWS:
        assert f"\n{row} " in module.__doc__
    csv = tmp_path / "poses.csv"
    csv.write_text("# name,qw,qx,qy,qz,tx,ty,tz\nb.jpg,0,0,0,1,1,2,3\na.jpg,1,0,0,0,0,0,0\n")
    a, b = getattr(module, entry.reader)(csv, scale=2.0)
    assert (a.image, b.image) == ("a.jpg", "b.jpg")
    np.testing.assert_allclose(b.c2w.numpy(), [[-1, 0, 0, 2], [0, -1, 0, 4], [0, 0, 1, -6], [0, 0, 0, 1]], atol=1e-12)
    csv.write_text("a.jpg,1,0,0,0,nan,0,0\n")
    with pytest.raises(ValueError, match=r"poses.csv line 1 contains non-finite values"):
        getattr(module, entry.reader)(csv)
