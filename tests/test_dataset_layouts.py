"""One vocabulary of dataset layouts: the registry's names, detected by one rule, offered by every command."""

from __future__ import annotations

import pytest

from cylindersplat.cli import build_parser
from cylindersplat.data.datasets import DATASETS
from cylindersplat.data.preview import open_dataset
from cylindersplat.dataset_layouts import DATASET_LAYOUTS, detect_layout, layout_name


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
