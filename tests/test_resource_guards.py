"""Guards of the library: memory estimated before reconstructing, weights and checkpoints written atomically,
library calls refusing bad arguments with readable errors."""

import errno
import os

import pytest
import torch

from cylindersplat.gaussians import Gaussians
from cylindersplat.inference import reconstruct_gaussians
from cylindersplat.inference.memory import ReconstructionMemoryError, check_forward_memory, forward_memory
from cylindersplat.model import from_config, get_config, load_model, save_model
from cylindersplat.render import render_equirect
from cylindersplat.utils import atomic
from model_inputs import make_inputs

GiB = 2**30


# -- memory before the model forward ----------------------------------------------------------------------

def test_forward_memory_estimate_is_conservative_but_not_absurd():
    # Measured peaks (CPU, float32, see inference/memory.py): tiny 1 view 512x1024 309 MiB, paper 964 MiB.
    tiny, paper = get_config("tiny_paper"), get_config("paper")
    assert 309 * 2**20 <= forward_memory(tiny, 1, 512, 1024) <= 3 * 309 * 2**20
    assert 964 * 2**20 <= forward_memory(paper, 1, 512, 1024) <= 3 * 964 * 2**20
    # Grows with views and pixels; the pixel branch alone needs less than both branches.
    assert (forward_memory(paper, 2, 512, 1024) > forward_memory(paper, 1, 512, 1024)
            > forward_memory(paper, 1, 256, 512))
    assert forward_memory(paper, 1, 512, 1024, mode="pixel") < forward_memory(paper, 1, 512, 1024)


def test_a_reconstruction_that_cannot_fit_is_refused_before_running(monkeypatch, tiny_model):
    images, depth, c2w = make_inputs(views=2, height=64, width=128)
    need = forward_memory(tiny_model.config, 2, 64, 128)
    monkeypatch.setattr("cylindersplat.render.rasterize.available_memory", lambda device: need - 1)
    calls = []
    monkeypatch.setattr(type(tiny_model), "forward", lambda *a, **k: calls.append(1))
    with pytest.raises(ReconstructionMemoryError, match=r"2 panorama\(s\) at 64x128 needs about .* free on cpu.*32x64"):
        reconstruct_gaussians(tiny_model, images[0], depth[0], c2w[0])
    assert calls == []  # refused before the forward pass
    assert isinstance(ReconstructionMemoryError("x"), MemoryError)  # the CLI prints it as one line
    monkeypatch.setattr("cylindersplat.render.rasterize.available_memory", lambda device: need)
    assert check_forward_memory(tiny_model.config, 2, 64, 128, "cpu") == need
    monkeypatch.setattr("cylindersplat.render.rasterize.available_memory", lambda device: None)  # unknown: no check
    assert check_forward_memory(tiny_model.config, 2, 64, 128, "cpu") == need


def test_no_smaller_resolution_is_suggested_when_none_fits(monkeypatch):
    monkeypatch.setattr("cylindersplat.render.rasterize.available_memory", lambda device: 2**20)
    with pytest.raises(ReconstructionMemoryError, match=r"use a smaller --resolution, fewer panoramas") as info:
        check_forward_memory(get_config("paper"), 3, 512, 1024, "cpu")
    assert "e.g." not in str(info.value) and "GiB (estimate) but 1 MiB are free" in str(info.value)


# -- atomic weights and checkpoints ------------------------------------------------------------------------

def _fill_disk_after(monkeypatch, nbytes, code=errno.ENOSPC):
    """Make atomic writes fail with ``code`` after ``nbytes`` bytes, as a disk that fills up does."""
    real_open = open

    class Full:
        def __init__(self, path, mode):
            self.f = real_open(path, mode)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, data):
            self.f.write(bytes(data[:nbytes]))
            raise OSError(code, os.strerror(code))

    monkeypatch.setattr(atomic, "open", Full, raising=False)


def test_weights_survive_a_full_disk(tmp_path, monkeypatch, tiny_model):
    from cylindersplat.cli import expected_failure

    path = tmp_path / "model.safetensors"
    save_model(tiny_model, path)
    before = path.read_bytes()
    _fill_disk_after(monkeypatch, 1000)
    with pytest.raises(OSError) as info:
        save_model(from_config("tiny_paper", mode="pixel"), path)
    assert info.value.filename == str(path)  # the file being written, not its temporary name
    assert expected_failure(info.value) == f"disk full while writing {path}: free space or choose another --out"
    monkeypatch.undo()
    assert path.read_bytes() == before and load_model(path).mode == "both"
    assert [p.name for p in tmp_path.iterdir()] == ["model.safetensors"]


def test_training_checkpoints_survive_a_full_disk(tmp_path, monkeypatch, tiny_model):
    from cylindersplat.training.checkpoint import read_state, resolve_checkpoint, save_checkpoint

    state = {"global_step": 1, "stages": [1], "stage_index": 0, "stage_step": 1, "optimizer": None, "scheduler": None,
             "rng": {}}
    save_checkpoint(tmp_path, tiny_model, state)
    _fill_disk_after(monkeypatch, 10, errno.EDQUOT)
    with pytest.raises(OSError, match="quota"):
        save_checkpoint(tmp_path, tiny_model, {**state, "global_step": 2})
    monkeypatch.undo()
    latest = resolve_checkpoint(tmp_path)
    assert latest.name == "step_0000001" and read_state(latest)["global_step"] == 1
    assert resolve_checkpoint(tmp_path / "step_0000001") == latest  # the earlier checkpoint is whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["latest", "step_0000001"]  # the half one is removed


def test_atomic_outputs_get_ordinary_permissions(tmp_path):
    mask = os.umask(0o022)
    try:
        new = atomic.atomic_write_text(tmp_path / "new.txt", "x")
        assert new.stat().st_mode & 0o777 == 0o644  # what open() gives, not mkstemp's 0600
        os.chmod(new, 0o640)
        atomic.atomic_write_text(new, "y")
        assert new.stat().st_mode & 0o777 == 0o640  # a replaced file keeps its permissions
    finally:
        os.umask(mask)


# -- readable errors from library calls ---------------------------------------------------------------------

def _scene():
    one = lambda *v: torch.tensor([v])  # noqa: E731
    return Gaussians.from_rgb(one(0.0, 0.0, 2.0), one(0.1, 0.1, 0.1), one(1.0, 0.0, 0.0, 0.0), torch.ones(1),
                              one(1, 0, 0))


@pytest.mark.parametrize("kwargs,error,message", [
    (dict(c2w=torch.zeros(0, 4, 4)), ValueError, r"no cameras \(shape \(0, 4, 4\)\)"),
    (dict(height=8.5, width=17), ValueError, "height must be a positive integer, got 8.5"),
    (dict(height=8.0, width=16), ValueError, "height must be a positive integer, got 8.0"),
    (dict(height=0, width=0), ValueError, "height must be a positive integer"),
    (dict(height=8, width=15), ValueError, "width == 2 \\* height"),
    (dict(background=(0.0, 0.0)), ValueError, r"background must be RGB, \(3,\) or one per camera"),
    (dict(background=torch.zeros(2, 3)), ValueError, r"background must be RGB.*got \(2, 3\)"),
    (dict(background=(float("nan"), 0.0, 0.0)), ValueError, "background must be finite.*nan"),
    (dict(background=(0.0, float("inf"), 0.0)), ValueError, "background must be finite.*inf"),
    (dict(background="red"), TypeError, "background must be RGB numbers"),
    (dict(c2w=torch.eye(4).tolist()), TypeError, "c2w must be a torch.Tensor"),
])
def test_render_equirect_refuses_bad_arguments_readably(kwargs, error, message):
    args = {"gaussians": _scene(), "c2w": torch.eye(4), "height": 8, "width": 16, **kwargs}
    with pytest.raises(error, match=message):
        render_equirect(**args)


def test_a_safetensors_header_is_not_mistaken_for_a_pickle(tmp_path):
    """Its first byte (the header length's low byte) can be 0x80, as a pickle's is."""
    from safetensors.torch import save_file

    from cylindersplat.model.checkpoint import check_weights_file

    path = tmp_path / "w.safetensors"
    for n in range(256):
        save_file({"a": torch.zeros(1)}, str(path), metadata={"k": "v" * n})
        if path.read_bytes()[0] == 0x80:
            break
    assert path.read_bytes()[0] == 0x80
    check_weights_file(path)  # no error
    torch.save({"a": torch.zeros(1)}, path)
    with pytest.raises(ValueError, match="PyTorch pickle"):
        check_weights_file(path)
