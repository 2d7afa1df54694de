"""Same as `cylindersplat bench render` (see cylindersplat/benchmarks/render.py for what it measures)."""

from cylindersplat.benchmarks.render import main

if __name__ == "__main__":
    main()
