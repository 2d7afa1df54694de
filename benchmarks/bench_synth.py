"""Same as `cylindersplat bench synth` (see cylindersplat/benchmarks/synth.py for what it measures)."""

from cylindersplat.benchmarks.synth import main

if __name__ == "__main__":
    main()
