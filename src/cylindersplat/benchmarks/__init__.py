"""Benchmarks behind ``cylindersplat bench`` (also runnable as ``python benchmarks/bench_<name>.py``).

* ``render``: the equirect rasterizer, forward and forward+backward, median time and peak memory,
  optionally against the cubemap route and with a per-stage breakdown;
* ``model``: the model's forward (and backward) for 1-4 input views per preset;
* ``train``: time and peak memory of one training step of each curriculum stage;
* ``synth``: procedural panorama generation throughput;
* ``gsplat_compare``: our pinhole renderer against gsplat's (when installed, on CUDA).

Figures, with the machine that produced them, go to ``benchmarks/RESULTS.md``.
"""

BENCHMARKS = ("render", "model", "train", "synth", "gsplat_compare")
