"""Experiments built on the library: the ablation study (``cylindersplat ablate``)."""
