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
# ``t[i] = 0.5``: PyTorch makes the number a host tensor and copies it, which on CUDA waits for the device (the
# RGB background did so three times a render; seen by CUDA's sync watch on an H100, 2026-11-27). ``t[i].fill_(x)``
# does not. Counted only where the value is a Python number.
NUMBER_WRITES = ("__setitem__",)


def waits_during(fn, methods=HOST_COPIES + IMPLICIT + NUMBER_WRITES) -> list[tuple[str, str, str]]:
    """``(method, file under cylindersplat/, function)`` of every call of ``methods`` made directly from
    cylindersplat's code while ``fn`` runs, in order (libraries' own calls, e.g. Triton's interpreter copying
    tensors, are not counted)."""
    found = []
    originals = {name: getattr(torch.Tensor, name) for name in methods}

    def watched(name):
        original = originals[name]

        def method(self, *args, **kwargs):
            caller = sys._getframe(1).f_code
            counted = name not in NUMBER_WRITES or isinstance(args[1], (bool, int, float, complex))
            if counted and caller.co_filename.startswith(ROOT):
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
