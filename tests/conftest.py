"""Test-suite set-up shared by every module."""

import os

import torch

# Without a GPU the Triton backend's kernels run in Triton's CPU interpreter. The variable must be set
# before the kernels are first imported, i.e. before any test renders with backend="triton".
if not torch.cuda.is_available():
    os.environ.setdefault("TRITON_INTERPRET", "1")
