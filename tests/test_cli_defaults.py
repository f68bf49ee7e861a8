"""The command line's defaults are the ones the documentation recommends: ``diekf`` for a distributed team
(``swarmloc team``, ``swarmloc node``), and ``evaluate`` / ``compare`` run the recommended ``iekf`` and ``diekf``
among their default estimators; ``--help`` says so."""

from __future__ import annotations

import argparse

import pytest

from swarmloc.cli import build_parser
from swarmloc.cli.options import SEED_MAX, real, seed

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(
    "argv",
    [["team", "--out", "o"], ["node", "--team", "t", "--robot", "0", "--source", "sim:random", "--no-auth"]],
    ids=["team", "node"],
)
def test_team_and_node_run_diekf_by_default(argv):
    assert build_parser().parse_args(argv).estimator == "diekf"


@pytest.mark.parametrize("command", ["team", "node"])
def test_team_and_node_help_name_the_default(command, capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "default diekf, the recommended distributed filter" in text


def test_evaluate_runs_iekf_and_diekf_by_default(capsys):
    args = build_parser().parse_args(["evaluate", "events", "x.csv"])
    names = args.estimators.split(",")
    assert {"iekf", "diekf"} <= set(names) and {"dr", "cekf", "rdl"} <= set(names)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["evaluate", "--help"])
    text = "".join(capsys.readouterr().out.split())  # argparse wraps the list anywhere
    assert f"(default{args.estimators})" in text


def test_compare_default_estimators_include_iekf_and_diekf(monkeypatch):
    """``compare`` with no ``--estimators`` runs the same default list (on a 3-D scenario, those of it with an
    SE(3) form): the list handed to :func:`swarmloc.experiments.compare.compare` is captured."""
    import swarmloc.experiments.compare as cmp
    from swarmloc.cli import main
    from swarmloc.estimators import ESTIMATORS_SE3

    seen: dict[str, list[str]] = {}

    def fake(scenario, names, **_kw):
        seen[scenario] = list(names)
        raise ValueError("stop here")

    monkeypatch.setattr(cmp, "compare", fake)
    assert main(["compare", "--quiet"]) == 2
    assert main(["compare", "--scenario", "sim:3d", "--quiet"]) == 2
    assert {"iekf", "diekf", "cekf", "rdl"} <= set(seen["sim:random"])
    assert "diekf" in seen["sim:3d"] and set(seen["sim:3d"]) <= set(ESTIMATORS_SE3)
    assert [e for e in seen["sim:random"] if e in ESTIMATORS_SE3] == seen["sim:3d"]


def _options(parser: argparse.ArgumentParser):
    """Every option of ``parser`` and of its subcommands' parsers, as ``(command, action)``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from ((f"{name} {c}".strip(), a) for c, a in _options(sub))
        else:
            yield "", action


def test_no_option_of_either_command_line_takes_a_bare_float_or_any_integer_as_a_seed():
    """A bare ``float`` takes ``nan`` and ``inf``: every real-valued option is typed ``real`` (finite) instead; every
    seed option ``seed`` (an integer in ``[0, 2^32 - 1]``: ``demo --seed -1`` was a traceback)."""
    from swarmloc_studies.cli import build_parser as studies_parser

    seen = seeds = 0
    for parser in (build_parser(), studies_parser()):
        for command, action in _options(parser):
            assert action.type is not float, f"{command} {action.option_strings} takes a bare float"
            seen += action.type is real
            if action.dest in ("seed", "first_seed"):
                assert action.type is seed, f"{command} {action.option_strings} takes any integer as a seed"
                seeds += 1
    assert seen >= 25  # the durations, timeouts, gates, rates ... of both command lines
    assert seeds >= 8  # demo, simulate, node, team, server, ros, map, reproduce


@pytest.mark.parametrize(
    "argv",
    [
        ["evaluate", "mrclam", "d", "--duration", "nan"],
        ["team", "--max-wall", "inf"],
        ["compare", "--p-detect", "Infinity"],
        ["node", "--team", "t", "--robot", "0", "--no-auth", "--start-timeout", "NaN"],
        ["evaluate", "events", "x.csv", "--gate", "ten"],
        ["demo", "--seed", "-1"],
        ["map", "--first-seed", str(2**32)],
    ],
)
def test_a_real_valued_option_refuses_what_is_not_a_finite_number(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {argv[-2]}" in err and f"got '{argv[-1]}'" in err and ("number" in err or "seed" in err)
    assert real("2.5") == 2.5 and real("-1e3") == -1000.0 and seed("0") == 0 and seed(str(SEED_MAX)) == SEED_MAX


def test_evaluate_refuses_a_negative_gate_and_turns_the_gate_off_at_0(tmp_path, capsys):
    """(``--gate -1`` turned the gate off as 0 does.)"""
    from swarmloc.cli import main

    events = tmp_path / "events.csv"
    assert main(["simulate", "--robots", "2", "--duration", "3", "--out", str(tmp_path)]) == 0
    assert main(["evaluate", "events", str(events), "--quiet", "--estimators", "dekf", "--gate", "-1"]) == 2
    assert "--gate: a probability in (0, 1), or 0 to turn the gate off, got -1.0" in capsys.readouterr().err
    assert main(["evaluate", "events", str(events), "--quiet", "--estimators", "dekf", "--gate", "0", "--json"]) == 0
