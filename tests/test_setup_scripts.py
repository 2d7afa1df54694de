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
        can_make_venvs = subprocess.run([candidate, "-c", "import ensurepip, venv"],
                                        capture_output=True).returncode == 0
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


# --- scripts/test.sh installs nothing system-wide unless asked ---------------------------------------------------

STUB = """#!/usr/bin/env bash
echo "$(basename "$0") $*" >> "$CALLS"
{body}
"""
STUBS = {  # what each stand-in does besides logging its call
    "python": "exit 0",  # pip, the torch check and pytest: all succeed
    "apt-get": ('[ "$1" = install ] && printf \'#!/bin/sh\\necho chromium 1\\n\' > "$STUB_BIN/chromium" '
                '&& chmod +x "$STUB_BIN/chromium"; exit 0'),
    "npm": ('prefix=$(echo "$*" | sed -n "s/.*--prefix \\\\([^ ]*\\\\).*/\\\\1/p"); mkdir -p "$prefix/bin" && '
            'printf \'#!/bin/sh\\necho 3.7.0\\n\' > "$prefix/bin/splat-transform" && chmod +x '
            '"$prefix/bin/splat-transform"'),
    "node": 'echo 22',
    "id": 'echo 0',  # root: apt-get would run
}
RUFF = "python -m ruff check src tests studies benchmarks scripts"
TOOLS = ("bash", "dirname", "mktemp", "grep", "tail", "rm", "timeout", "uname", "cat", "mkdir", "chmod", "sed",
         "basename", "printf", "env")


@pytest.fixture()
def test_sh(tmp_path):
    """A copy of the scripts in a stand-in clone, run with stand-ins for python, apt-get, npm and node on a PATH
    that holds nothing else (no chromium): -> run(*args, **env) -> (result, calls, stand-in clone)."""
    import shutil

    repo = tmp_path / "repo"
    shutil.copytree(SCRIPTS, repo / "scripts")
    bin_dir, home = tmp_path / "bin", tmp_path / "home"
    bin_dir.mkdir()
    home.mkdir()
    for name, body in STUBS.items():
        (bin_dir / name).write_text(STUB.format(body=body))
        (bin_dir / name).chmod(0o755)
    for tool in TOOLS:
        (bin_dir / tool).symlink_to(shutil.which(tool))
    calls = tmp_path / "calls.log"

    def run(*args: str, **env: str):
        calls.write_text("")
        result = subprocess.run(["bash", str(repo / "scripts" / "test.sh"), *args], capture_output=True, text=True,
                                env={"PATH": str(bin_dir), "HOME": str(home), "CALLS": str(calls),
                                     "STUB_BIN": str(bin_dir),
                                     "PYTHON": str(bin_dir / "python"), **env})
        assert not any(home.iterdir()), list(home.iterdir())  # nothing written to the home folder
        return result, calls.read_text().splitlines(), repo

    return run


def test_test_sh_installs_nothing_system_wide_without_the_flag(test_sh):
    result, calls, repo = test_sh("-x")
    assert result.returncode == 0, result.stderr
    assert not any(call.startswith("apt-get") for call in calls), calls
    npm = [call for call in calls if call.startswith("npm ")]
    assert len(npm) == 1 and f"--prefix {repo}/.tools " in npm[0] and f"--cache {repo}/.tools/npm-cache" in npm[0]
    assert calls[-1] == "python -m pytest -q -x"
    assert RUFF in calls  # linted before the tests (the last call)
    assert result.stderr.splitlines() == [
        "test.sh: optional part 'browser' skipped: chromium would be installed system-wide (apt-get); run "
        "`bash scripts/test.sh --with-system-tools` (or CYLINDERSPLAT_SYSTEM_INSTALLS=1) to install it; its tests "
        "will skip"]


@pytest.mark.parametrize("how", ["flag", "environment"])
def test_test_sh_installs_chromium_when_asked(test_sh, how):
    args, env = (["--with-system-tools"], {}) if how == "flag" else ([], {"CYLINDERSPLAT_SYSTEM_INSTALLS": "1"})
    result, calls, _ = test_sh(*args, "-m", "not slow", **env)
    assert result.returncode == 0 and result.stderr == "", result.stderr
    assert "apt-get update -qq" in calls and "apt-get install -y -qq chromium" in calls
    assert calls[-1] == "python -m pytest -q -m not slow"  # the flag is test.sh's, not pytest's


def test_test_sh_stops_at_a_ruff_finding_before_the_tests(test_sh, tmp_path):
    (tmp_path / "bin" / "python").write_text(STUB.format(body='[ "$2" = ruff ] && exit 1; exit 0'))
    result, calls, _ = test_sh()
    assert result.returncode == 1
    assert calls[-1] == RUFF and not any(call.startswith("python -m pytest") for call in calls), calls


def test_test_sh_says_which_optional_part_it_skipped_and_why(test_sh, tmp_path):
    (tmp_path / "bin" / "node").unlink()  # no Node.js: splat-transform cannot be installed
    (tmp_path / "bin" / "npm").unlink()
    result, calls, _ = test_sh()
    assert result.returncode == 0 and not any(call.startswith(("npm", "apt-get")) for call in calls)
    assert result.stderr.splitlines()[0] == (
        "test.sh: optional part 'formats' skipped: formats: Node.js and npm are needed (Debian: apt-get install "
        "nodejs npm; or https://nodejs.org); its tests will skip")
    quiet, _, _ = test_sh(CYLINDERSPLAT_SKIP_OPTIONAL="1")
    assert quiet.stderr == ("test.sh: no optional part installed (CYLINDERSPLAT_SKIP_OPTIONAL is "
                            "set); their tests will skip\n")
