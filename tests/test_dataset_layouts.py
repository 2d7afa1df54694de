"""One registry of dataset layouts: one DatasetSpec per layout, detected by one rule, asked by every command."""

from __future__ import annotations

import ast
import os
from pathlib import Path

import pytest

from cylindersplat.cli import build_parser
from cylindersplat.data.datasets import DATASETS
from cylindersplat.data.preview import open_dataset
from cylindersplat.dataset_layouts import (
    DATASET_LAYOUTS,
    DATASET_SPECS,
    IS_ONE,
    DatasetSpec,
    dataset_spec,
    detect_layout,
    layout_name,
)


def test_every_command_names_layouts_like_the_registry(tmp_path):
    assert tuple(DATASETS) == DATASET_LAYOUTS
    parser = build_parser()
    for name in DATASET_LAYOUTS:
        assert parser.parse_args(["eval", "--data", "D", "--layout", name]).format == name
        assert parser.parse_args(["eval", "--data", "D", "--format", name]).format == name  # the older spelling
        priors = parser.parse_args(["data", "priors", "--data", "D", "--net", "exported:n.pt2", "--name", "x",
                                    "--layout", name])
        assert priors.layout == name
    old = parser.parse_args(["data", "priors", "--data", "D", "--net", "exported:n.pt2", "--name", "x", "--layout",
                             "input", "--format", "npy"])
    assert (old.layout, old.file_format) == ("folder", "npy")  # older names keep working
    assert layout_name("input") == "folder"
    with pytest.raises(ValueError, match="unknown dataset layout 'panogrf'"):
        layout_name("panogrf")


def test_a_folder_of_posed_panoramas_is_one_layout_everywhere(panorama_folder):  # conftest.py
    path = panorama_folder[0]
    assert detect_layout(path) == "folder"
    assert type(open_dataset(path)).__name__ == "FolderDataset"
    from cylindersplat.data.depth_prior.precompute import prior_frames

    root, frames, layout = prior_frames(path)
    assert layout == "folder" and len(frames) == 2
    assert prior_frames(path, layout="input")[2] == "folder"


# -- the registry: one DatasetSpec per layout, asked by every command ---------------------------------------------

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "cylindersplat"
# the modules that must ask the registry instead of naming layouts: every command, and the data modules that
# used to dispatch on the layout themselves
ASKERS = sorted((PACKAGE / "commands").glob("*.py")) + [PACKAGE / "data" / "preview.py",
                                                         PACKAGE / "data" / "datasets.py",
                                                         PACKAGE / "data" / "depth_prior" / "precompute.py"]
DATASET_CLASSES = {"SyntheticDataset", "PanoGRFDataset", "Loc360Dataset", "FolderDataset"}


def _layout_dispatch(path: Path) -> list[str]:
    """``x == "loc360"``, ``x in ("synthetic", ...)``, ``isinstance(ds, FolderDataset)`` and the like in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Compare):
            for side in [node.left, *node.comparators]:
                items = side.elts if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else [side]
                names = [i.value for i in items if isinstance(i, ast.Constant) and i.value in DATASET_LAYOUTS]
                found += [f"{path.name}:{node.lineno} compares with {name!r}" for name in names]
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance" and len(node.args) == 2:
            classes = node.args[1].elts if isinstance(node.args[1], ast.Tuple) else [node.args[1]]
            found += [f"{path.name}:{node.lineno} isinstance {c.id}" for c in classes
                      if isinstance(c, ast.Name) and c.id in DATASET_CLASSES]
    return found


def test_no_command_dispatches_on_the_layout_itself(tmp_path):
    offenders = [hit for path in ASKERS for hit in _layout_dispatch(path)]
    assert not offenders, f"ask the layout's DatasetSpec (dataset_layouts.dataset_spec) instead: {offenders}"
    own = tmp_path / "own.py"  # the scan finds what it looks for
    own.write_text('if args.format == "loc360" or layout in ("folder", "x"):\n    isinstance(d, FolderDataset)\n')
    assert len(_layout_dispatch(own)) == 3


def test_every_layout_has_one_spec_with_what_the_commands_ask():
    for name in DATASET_LAYOUTS:
        spec = dataset_spec(name)
        assert spec.name == name and callable(spec.detect) and callable(spec.open) and callable(spec.frames)
        assert spec.depth_range[0] < spec.depth_range[1]
    assert dataset_spec("input") is dataset_spec("folder")  # an alias asks its layout's spec
    assert dataset_spec("pano_grf").depth_range == (0.45, 10.0)  # PanoGRF's evaluation range, as before


def test_data_info_and_preview_describe_a_360loc_root(tmp_path, capsys):
    from cylindersplat.cli import main
    from test_data_loaders import write_loc360

    write_loc360(tmp_path / "loc", frames=5)
    assert detect_layout(tmp_path / "loc") == "loc360"
    assert main(["data", "info", "--data", str(tmp_path / "loc"), "--count", "1"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("Loc360Dataset: ") and "views all_between" in out and "occluded n/a (no depth)" in out
    assert main(["data", "preview", "--data", str(tmp_path / "loc"), "--out", str(tmp_path / "sheet.png"),
                 "--count", "1", "--height", "8"]) == 0
    assert (tmp_path / "sheet.png").is_file()
    assert main(["data", "info", "--data", str(tmp_path / "loc"), "--views", "two_view"]) == 1
    assert "360Loc has its own protocol" in capsys.readouterr().err


# A toy layout in a few lines: a file `toy.txt` naming a synthetic dataset beside it. Its spec and one registry
# line (here register_dataset, in the package a line of DATASET_SPECS) are all a new dataset needs.
def _toy_open(root, *, views="two_view", split=None, **options):
    from cylindersplat.data.synthetic import SyntheticDataset

    return SyntheticDataset(Path(root) / Path(root, "toy.txt").read_text().strip(), views=views, **options)


def _toy_frames(root, split="all"):
    from cylindersplat.data.depth_prior import NoPrior

    return _toy_open(root, depth_prior=NoPrior())


def _toy_inspect(root, *, views, resolution=None):
    from cylindersplat.data.depth_prior import NoPrior

    return _toy_open(root, views=views, resolution=resolution, depth_prior=NoPrior())


TOY = DatasetSpec("toy", "a toy.txt folder", lambda path: IS_ONE if (path / "toy.txt").is_file() else 0, _toy_open,
                  _toy_frames, _toy_inspect, options=("scenes",), depth_range=(0.1, 100.0))


@pytest.fixture()
def toy_registered(monkeypatch, synth_dataset, tmp_path):
    monkeypatch.setitem(DATASET_SPECS, "toy", TOY)
    root = tmp_path / "toy"
    root.mkdir()
    (root / "toy.txt").write_text(os.path.relpath(synth_dataset(2, seed=0), root))
    return root


def test_a_new_dataset_is_one_spec_and_one_registry_line(toy_registered, tmp_path, capsys):
    from cylindersplat.cli import main
    from cylindersplat.data.datasets import DATASETS, make_dataset
    from cylindersplat.data.depth_prior.precompute import prior_frames
    from cylindersplat.training import load_config

    root = toy_registered
    assert detect_layout(root) == "toy" and "toy" in DATASETS
    dataset = make_dataset("toy", root, views="two_view", scenes=["00000001"])  # options the spec lists
    assert len(dataset) == 1 and dataset[0].target_images.shape[-2:] == (32, 64)
    _, frames, layout = prior_frames(root)
    assert layout == "toy" and len(frames) == 2 * 3
    assert type(open_dataset(root)).__name__ == "SyntheticDataset"
    assert main(["data", "info", "--data", str(root), "--count", "1", "--occlusion", "0"]) == 0
    assert "2 examples" in capsys.readouterr().out
    assert load_config("tiny", ["data.format=toy", f"data.root={root}"]).data.format == "toy"
    with pytest.raises(ValueError, match="data.format must be one of .*toy; got 'toi'"):
        load_config("tiny", ["data.format=toi"])
    # eval asks the spec for the depth range and which options apply (--scenes: yes, --views: no)
    out = tmp_path / "eval"
    assert main(["eval", "--data", str(root), "--layout", "toy", "--no-model", "--scenes", "00000000", "--out",
                 str(out), "--lpips", "off", "--pictures", "0", "--fills", "none"]) == 0
    assert "(1 examples)" in (out / "results.md").read_text()
    assert main(["eval", "--data", str(root), "--layout", "toy", "--no-model", "--views", "3"]) == 1
    assert "--views, --gap and --views-layout choose 360Loc's context frames" in capsys.readouterr().err
