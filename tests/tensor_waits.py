"""Which ``torch.Tensor`` methods that wait for the device (a host copy, or a Python value of a device tensor)
cylindersplat's own code calls while a function runs: the host-synchronisation tests of the render path
(``test_render_triton_sync.py``) and of input validation (``test_validation_syncs.py``) share this watch."""

import os
import sys

import torch

import cylindersplat

ROOT = os.path.dirname(cylindersplat.__file__)
HOST_COPIES = ("item", "tolist", "cpu", "numpy")  # explicit
IMPLICIT = ("__bool__", "__int__", "__float__", "__index__", "nonzero")  # a Python value or a data-dependent size


def waits_during(fn, methods=HOST_COPIES + IMPLICIT) -> list[tuple[str, str, str]]:
    """``(method, file under cylindersplat/, function)`` of every call of ``methods`` made directly from
    cylindersplat's code while ``fn`` runs, in order (libraries' own calls, e.g. Triton's interpreter copying
    tensors, are not counted)."""
    found = []
    originals = {name: getattr(torch.Tensor, name) for name in methods}

    def watched(name):
        original = originals[name]

        def method(self, *args, **kwargs):
            caller = sys._getframe(1).f_code
            if caller.co_filename.startswith(ROOT):
                found.append((name, os.path.relpath(caller.co_filename, ROOT), caller.co_name))
            return original(self, *args, **kwargs)
        return method

    try:
        for name in originals:
            setattr(torch.Tensor, name, watched(name))
        fn()
    finally:
        for name, original in originals.items():
            setattr(torch.Tensor, name, original)
    return found
