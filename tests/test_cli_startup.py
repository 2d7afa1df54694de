"""The command line starts fast: building its parsers imports no torch (about 1.5 s: a command's choices that need
it are read when used), a command's run or --help builds only its own parser, and --version none; the whole parser
is still there for the top-level help and for a command that does not exist."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cylindersplat import cli

IMPORTS_TORCH = """import sys
from cylindersplat import cli
try:
    cli.main({!r})
except SystemExit:  # (what --help and --version end with)
    pass
print('torch' in sys.modules)
"""


@pytest.mark.parametrize("argv", [["render", "--help"], ["--debug", "view", "--help"], ["--version"], ["--help"],
                                  ["ablate", "--help"], ["data", "--help"], ["data", "import-poses", "--help"]])
def test_a_commands_help_and_the_version_do_not_import_torch(argv):
    code = IMPORTS_TORCH.format(argv)
    env = {**os.environ, "PYTHONPATH": str(Path(cli.__file__).parents[1])}  # this checkout's package
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert run.returncode == 0 and run.stdout.strip().splitlines()[-1] == "False", run.stderr


def test_the_command_named_gets_its_whole_parser_and_the_others_their_names():
    assert cli._command_in(["--debug", "render", "--ply", "x.ply"]) == "render"
    assert cli._command_in(["rendr"]) is None and cli._command_in([]) is None
    assert cli._command_in(["--version"]) == "" and cli._command_in(["--version", "-h"]) is None
    whole, one = cli.build_parser(), cli.build_parser("render")
    names = [m.rsplit(".", 1)[1] for m in cli.subcommand_modules()]
    for parser in (whole, one):
        sub = next(a for a in parser._actions if a.dest == "command")
        assert list(sub.choices) == names
    args = ["render", "--ply", "x.ply", "--views", "v.json", "--fov", "70"]
    assert vars(one.parse_args(args)) == vars(whole.parse_args(args))
    with pytest.raises(SystemExit):
        one.parse_args(["render", "--bogus"])


def test_a_mistyped_command_is_named_with_every_choice(capsys):
    with pytest.raises(SystemExit):
        cli.main(["rendr"])
    err = capsys.readouterr().err
    assert "invalid choice: 'rendr'" in err and "'ablate'" in err and "'view'" in err


def test_lazy_package_names_load_at_first_use_and_unknown_ones_are_refused():
    code = """import sys
import cylindersplat.data as data
import cylindersplat.data.poses as poses
from cylindersplat.data.poses.registry import POSE_FORMATS
print('torch' in sys.modules, sorted(POSE_FORMATS) == sorted(poses.POSE_FORMATS))
from cylindersplat.data import read_rgb, SimulatedPriorConfig
print('torch' in sys.modules, read_rgb.__module__, 'read_rgb' in vars(data), 'FolderDataset' in dir(data))
try:
    data.nothing_here
except AttributeError as error:
    print(error)
"""
    env = {**os.environ, "PYTHONPATH": str(Path(cli.__file__).parents[1])}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines() == [
        "False True", "True cylindersplat.data.io True True",
        "module 'cylindersplat.data' has no attribute 'nothing_here'"], run.stdout
