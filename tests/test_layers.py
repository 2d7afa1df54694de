"""The package's layers, checked on the source with ``ast`` (docs/architecture.md draws them):

* nothing in the library imports the command line (``cylindersplat.cli``, ``cylindersplat.commands``) except the
  command line itself;
* the model does not reach into the renderer's modules;
* research (study scripts, their results, lab notes) lives in ``studies/``, not in the installed package.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "cylindersplat"
CLI_MODULES = ("cylindersplat.cli", "cylindersplat.commands", "cylindersplat.__main__", "cylindersplat.console")
# the files the installed package ships besides Python modules: presets, recipes, study catalogues, weights
PACKAGE_DATA_SUFFIXES = {".py", ".yaml", ".safetensors", ".typed"}
# modules that run as a program: the CLI, the bench modules (`cylindersplat bench`), a subprocess worker
ENTRY_POINTS = {"cli.py", "__main__.py", "data/poses/_colmap_worker.py"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import in ``path`` (relative imports resolved; ``from X import
    Y`` also counts ``X.Y``, which may be a module)."""
    tree = ast.parse(path.read_text(), str(path))
    package = _module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package[: len(package) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found.append((node.lineno, base))
            found += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
    return found


def _library_files():
    for path in sorted(PACKAGE.rglob("*.py")):
        name = _module_name(path)
        if not name.startswith(CLI_MODULES):
            yield path


def _imports_of(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def test_imported_modules_resolves_relative_imports(tmp_path):
    source = PACKAGE / "data" / "preview.py"
    names = {name for _, name in imported_modules(source)}
    assert "cylindersplat.utils.atomic" in names and "cylindersplat.data.occlusion" in names


def test_no_library_module_imports_the_command_line():
    offenders = [f"{path.relative_to(PACKAGE)}:{line} imports {name}" for path in _library_files()
                 for line, name in imported_modules(path) if _imports_of(name, CLI_MODULES)]
    assert not offenders, f"the library must not import the CLI (move the shared piece to utils/): {offenders}"


def test_the_model_does_not_import_renderer_internals():
    model_files = sorted((PACKAGE / "model").rglob("*.py"))
    offenders = [f"{path.relative_to(PACKAGE)}:{line} imports {name}" for path in model_files
                 for line, name in imported_modules(path)
                 if name.startswith("cylindersplat.render.") and name.count(".") >= 2
                 and (PACKAGE / "render" / f"{name.split('.')[2]}.py").is_file()]
    assert not offenders, "model/ may use cylindersplat.render's public API only: " + "; ".join(offenders)


def test_no_study_script_or_results_file_is_inside_the_package():
    stray = [str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*")
             if p.is_file() and "__pycache__" not in p.parts and p.suffix not in PACKAGE_DATA_SUFFIXES]
    assert not stray, f"results, notes and figures belong in studies/ (or benchmarks/ for bench figures): {stray}"
    scripts = [str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py")
               if 'if __name__ == "__main__"' in p.read_text() and str(p.relative_to(PACKAGE)) not in ENTRY_POINTS
               and p.parent.name != "benchmarks"]
    assert not scripts, f"scripts belong in studies/ (research) or benchmarks/ (bench entry points): {scripts}"
    assert not (PACKAGE / "experiments").exists()
