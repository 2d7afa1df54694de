"""Issue 27, hostile or absurd weights files: one line naming the file, never a raw allocator/type error."""

import json

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from cylindersplat.errors import InputError
from cylindersplat.model.checkpoint import CONFIG_KEY
from cylindersplat.model.pretrained import from_pretrained


def _rewrite(source, target, tensors=None, config=None):
    """A copy of the weights file ``source`` with other tensors and/or another stored config."""
    with safe_open(str(source), "pt") as f:
        meta = f.metadata()
    if config is not None:
        stored = json.loads(meta[CONFIG_KEY])
        config(stored)
        meta = {**meta, CONFIG_KEY: json.dumps(stored)}
    state = load_file(str(source))
    save_file(tensors(state) if tensors else state, str(target), metadata=meta)
    return target


def test_no_weights_name_is_one_line():
    with pytest.raises(InputError) as info:
        from_pretrained(None)
    assert str(info.value) == ("weights must be a shipped model name (tiny-synth), a .safetensors file or a run "
                               "folder, got None")


def test_a_stored_config_of_the_wrong_type_is_named(tiny_checkpoint, tmp_path):
    bad = _rewrite(tiny_checkpoint, tmp_path / "abc.safetensors", config=lambda c: c.update(image_height="abc"))
    with pytest.raises(ValueError) as info:
        from_pretrained(bad)
    assert str(info.value) == (f"{bad}: its model config cannot be read by this version of cylindersplat "
                               "(image_height must be like 512, got 'abc')")


def test_a_stored_config_asking_for_terabytes_is_refused_before_allocating(tiny_checkpoint, tmp_path):
    bad = _rewrite(tiny_checkpoint, tmp_path / "huge.safetensors",
                   config=lambda c: c["attention"].update(dim=6 * 200_000))
    with pytest.raises(MemoryError, match=rf"^{bad}: its model config asks for [\d.e+]+ GiB of weights but [\d.e+]+ "
                                          r"GiB are free; is it the right file\?"):
        from_pretrained(bad)


@pytest.mark.parametrize("change,message", [
    (lambda t: t * 1e30, "reaches"),
    (lambda t: t.to(torch.int32), "is torch.int32, not floating point"),
])
def test_scaled_or_integer_weights_are_refused(tiny_checkpoint, tmp_path, change, message):
    bad = _rewrite(tiny_checkpoint, tmp_path / "bad.safetensors",
                   tensors=lambda s: {k: change(v) for k, v in s.items()})
    with pytest.raises(ValueError, match=message) as info:
        from_pretrained(bad)
    assert str(info.value).startswith(f"{bad}: weight ") and "\n" not in str(info.value)
