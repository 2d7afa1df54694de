"""Same as `cylindersplat bench model` (see cylindersplat/benchmarks/model.py for what it measures)."""

from cylindersplat.benchmarks.model import main

if __name__ == "__main__":
    main()
