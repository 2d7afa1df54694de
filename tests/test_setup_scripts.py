"""The set-up scripts pick a Python that will accept the installs: a virtual environment on a PEP 668 Python."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"

FAKE_PYTHON = """#!/usr/bin/env bash
# A stand-in interpreter: answers scripts/_python.sh's question with $FAKE_KIND; "-m venv DIR" makes DIR/bin/python.
if [ "$1" = "-m" ] && [ "$2" = "venv" ]; then
    [ -n "$FAKE_NO_VENV" ] && exit 1
    mkdir -p "$3/bin" && printf '#!/bin/sh\\n' > "$3/bin/python" && chmod +x "$3/bin/python"; exit 0
fi
echo "$FAKE_KIND"
"""


def _choose(folder: Path, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", f". {SCRIPTS / '_python.sh'}; choose_python && echo \"PYTHON=$PYTHON\""],
                          cwd=folder, env={**os.environ, **env}, capture_output=True, text=True)


@pytest.fixture()
def fake(tmp_path):
    python = tmp_path / "bin" / "fakepython"
    python.parent.mkdir()
    python.write_text(FAKE_PYTHON)
    python.chmod(0o755)
    work = tmp_path / "repo"
    work.mkdir()
    env = {"CYLINDERSPLAT_BASE_PYTHON": str(python), "PYTHON": "", "FAKE_NO_VENV": ""}
    return work, python, env


def test_a_python_that_accepts_installs_is_used_as_it_is(fake):
    work, python, env = fake
    for kind in ("system", "venv"):  # e.g. the CI image's Python; an activated virtual environment
        out = _choose(work, {**env, "FAKE_KIND": kind})
        assert out.returncode == 0 and out.stdout.strip() == f"PYTHON={python}", out
        assert not (work / ".venv").exists() and out.stderr == ""
    assert _choose(work, {**env, "PYTHON": "/opt/my/python"}).stdout.strip() == "PYTHON=/opt/my/python"


def test_a_pep668_python_gets_a_virtual_environment(fake):
    work, python, env = fake
    out = _choose(work, {**env, "FAKE_KIND": "managed"})
    assert out.returncode == 0 and out.stdout.strip() == f"PYTHON={work}/.venv/bin/python", out
    assert "refuses system-wide installs (PEP 668)" in out.stderr and ". .venv/bin/activate" in out.stderr
    again = _choose(work, {**env, "FAKE_KIND": "system"})  # a later run keeps using it
    assert again.stdout.strip() == f"PYTHON={work}/.venv/bin/python" and again.stderr == ""


def test_without_venv_support_one_line_says_how(fake):
    work, python, env = fake
    out = _choose(work, {**env, "FAKE_KIND": "managed", "FAKE_NO_VENV": "1"})
    assert out.returncode == 1 and len(out.stderr.strip().splitlines()) == 1
    assert "apt-get install python3-venv" in out.stderr and "python3 -m venv .venv" in out.stderr
    assert not (work / ".venv").exists()


def _externally_managed_python() -> str | None:
    """A real PEP 668 interpreter on this machine (Debian's /usr/bin/python3), if any."""
    for candidate in ("/usr/bin/python3",):
        if not os.access(candidate, os.X_OK):
            continue
        stdlib = subprocess.run([candidate, "-c", "import sysconfig; print(sysconfig.get_path('stdlib'))"],
                                capture_output=True, text=True).stdout.strip()
        can_make_venvs = subprocess.run([candidate, "-c", "import ensurepip, venv"], capture_output=True).returncode == 0
        if stdlib and (Path(stdlib) / "EXTERNALLY-MANAGED").is_file() and can_make_venvs:
            return candidate
    return None


@pytest.mark.slow  # makes a real virtual environment (~15 s)
@pytest.mark.skipif(_externally_managed_python() is None,
                    reason="no externally managed (PEP 668) Python with venv support here")
def test_a_real_pep668_python_gets_a_working_virtual_environment(tmp_path):
    base = _externally_managed_python()
    out = _choose(tmp_path, {"CYLINDERSPLAT_BASE_PYTHON": base, "PYTHON": ""})
    assert out.returncode == 0, out.stderr
    venv_python = tmp_path / ".venv" / "bin" / "python"
    assert out.stdout.strip() == f"PYTHON={venv_python}"
    check = subprocess.run([str(venv_python), "-c", "import sys; print(sys.prefix != sys.base_prefix)"],
                           capture_output=True, text=True)
    assert check.stdout.strip() == "True"  # pip there installs without "externally-managed-environment"
