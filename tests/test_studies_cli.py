"""The research studies are a package apart (``studies/``): their commands are ``swarmloc-studies reproduce`` and
``swarmloc-studies bench``, not ``swarmloc``'s, and ``swarmloc demo`` runs without loading them."""

from __future__ import annotations

import subprocess
import sys

import pytest

from swarmloc.cli import build_parser as swarmloc_parser
from swarmloc_studies.cli import build_parser, main

pytestmark = pytest.mark.unit


def _commands(parser) -> set[str]:
    return set(parser._subparsers._group_actions[0].choices)


def test_the_study_commands_moved_from_swarmloc_to_swarmloc_studies():
    assert _commands(build_parser()) == {"reproduce", "bench"}
    assert not {"reproduce", "bench"} & _commands(swarmloc_parser())
    assert "demo" in _commands(swarmloc_parser())


def test_reproduce_refuses_an_unknown_target(tmp_path, capsys):
    assert main(["reproduce", "chapter9", "--out", str(tmp_path)]) == 2
    assert "swarmloc-studies reproduce: unknown target 'chapter9'" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["reproduce", "thesis", "--seeds", "-1"], "reproduce thesis: --seeds must be an integer in [1, 10000]"),
        (["reproduce", "thesis", "--seeds", "100000000"], "reproduce thesis: --seeds must be an integer in [1,"),
        (["reproduce", "thesis", "--reps", "0"], "reproduce thesis: --reps must be >= 1"),
        (["bench", "--quick", "--runs", "-1"], "bench: --runs must be an integer in [1, 10000]"),
        (["bench", "--quick", "--rounds", "0"], "bench: --rounds must be an integer in [1, 10000]"),
        (["bench", "--quick", "--duration", "-5"], "bench: --duration is seconds > 0"),
    ],
)
def test_the_study_commands_refuse_bad_counts_before_any_run(argv, says, tmp_path, capsys):
    """(``--seeds -1`` was a traceback after the demo and tables ran, ``--seeds 100000000`` ran on, and bench took a
    count below 1 as 1 and a negative duration as given.)"""
    out = tmp_path / "out"
    assert main([*argv, *(["--out", str(out)] if argv[0] == "reproduce" else [])]) == 2
    assert says in capsys.readouterr().err and not out.exists()


def test_the_demo_command_loads_no_study():
    """In a fresh interpreter: the parser and the demo's code (the command's import included) load no module of
    ``swarmloc_studies``."""
    script = (
        "import sys\n"
        "from swarmloc.cli import build_parser\n"
        "build_parser().parse_args(['demo', '--out', 'x'])\n"
        "import swarmloc.cli.commands.demo, swarmloc.experiments.thesis_demo\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'swarmloc_studies'))\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
