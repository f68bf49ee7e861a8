"""``swarmloc-studies bench``: the quick path's pieces on tiny sizes return the documented structure, with positive and
finite rates, ratios and fractions (no timing assertions: the machine is shared)."""

from __future__ import annotations

import json
import math

import pytest

from swarmloc_studies import bench as B
from swarmloc_studies import bench_command
from swarmloc_studies.bench_report import format_report
from swarmloc_studies.cli import main

pytestmark = pytest.mark.data


def _positive(x: object) -> bool:
    return isinstance(x, int | float) and math.isfinite(x) and x > 0


@pytest.fixture(scope="module")
def machine() -> dict:
    return B.machine_rates(copy_mb=1, matmul_n=32, repeats=1, single_thread=False)


def test_machine_rates(machine):
    assert _positive(machine["bandwidth_gb_s"]) and _positive(machine["gflops"])


def test_fusion_comparison_rates_ratio_and_fractions(machine):
    ticks = []
    f = B.fusion_comparison(engine_n=30, filterpy_n=8, neighbours=3, repeats=1, machine=machine, tick=ticks.append,
                            runs=3)  # fmt: skip
    assert len(ticks) == 2
    for key in ("filterpy", "engine"):  # filterpy and the engine are installed with the dev extra
        assert _positive(f[key]["robot_updates_per_s"]), f[key]
    assert f["filterpy"]["n"] == 8 and f["engine"]["n"] == 30
    lm = f["backends"]["numba, 1 landmark"]  # the step with one map landmark per robot as well
    assert lm["landmarks"] == 1 and _positive(lm["robot_updates_per_s"])
    for b in ("numpy", "numba", "jax"):
        r = f["backends"][b]
        assert r["over_filterpy"] == pytest.approx(r["robot_updates_per_s"] / f["filterpy"]["robot_updates_per_s"])
        assert r["runs"] == 3  # the median of three runs, between their extremes
        assert r["min_robot_updates_per_s"] <= r["robot_updates_per_s"] <= r["max_robot_updates_per_s"]
        assert r["max_robot_updates_per_s"] <= r["best_robot_updates_per_s"]  # a run's median is not above its best
        assert r["step_s"] == pytest.approx(30 / r["robot_updates_per_s"])
        assert len(r["load_1min"]) == 2 and all(x >= 0 for x in r["load_1min"])
    keys = ("engine_over_filterpy", "achieved_gb_s", "achieved_gflops", "fraction_of_bandwidth", "fraction_of_flops")
    for key in keys:
        assert _positive(f[key]), key


def test_filterpy_loop_does_the_documented_work():
    r = B.filterpy_fusion(5, neighbours=3, repeats=1)
    assert r["n"] == 5 and r["neighbours"] == 3 and _positive(r["robot_updates_per_s"])


def test_swarm_scaling_rows_and_slopes():
    s = B.swarm_scaling(sizes=(10, 20), steps=3, neighbour_sweep=(1, 3), sweep_n=20, isolate=False)
    assert [r["n"] for r in s["by_size"]] == [10, 20]
    assert [r["neighbours"] for r in s["by_neighbours"]] == [1, 3]
    for r in [*s["by_size"], *s["by_neighbours"]]:
        assert r["steps"] == 3 and r["robot_updates"] == 3 * r["n"]
        for key in ("wall_est_s", "us_per_robot_step", "peak_mem_bytes"):
            assert _positive(r[key]), key
    for key in ("slope_cost_per_robot_vs_size", "slope_wall_vs_size", "slope_cost_per_robot_vs_neighbours"):
        assert math.isfinite(s[key]), key


def test_loglog_slope():
    assert B.loglog_slope([1, 10, 100], [2, 20, 200]) == pytest.approx(1.0)
    assert math.isnan(B.loglog_slope([1], [1]))


def test_mrclam_replay_x_real_time(mrclam_root, mrclam6):
    ds = B.find_mrclam(mrclam_root)
    assert ds == mrclam6  # the bench finds dataset 6 in the folder holding it
    d = B.mrclam_replay(ds, duration=3.0, estimators=("dekf", "cekf", "rdl", "diekf"), landmarks=(True, False))
    assert d["duration_s"] == pytest.approx(3.0, abs=0.05)
    for key in ("landmarks_on", "landmarks_off"):
        rows = d[key]["estimators"]
        names = ("dekf", "cekf", "rdl", "diekf")
        assert set(rows) == {*names, *(f"{n}/engine" for n in names)}  # numba: the dev extra
        assert all(_positive(r["x_real_time"]) and _positive(r["wall_s"]) for r in rows.values())
        for name in names:
            eng, nodes = rows[f"{name}/engine"], rows[name]  # the same filter on the same events, another driver
            assert eng["pos_rmse_m"] == pytest.approx(nodes["pos_rmse_m"], abs=1e-9)
            assert eng["anees"] == pytest.approx(nodes["anees"], rel=1e-9)


def test_report_and_json_from_a_tiny_config(capsys, monkeypatch, mrclam_root_if_expected):
    tiny = B.BenchConfig(
        engine_n=20, filterpy_n=5, repeats=1, copy_mb=1, matmul_n=32, swarm_sizes=(10, 20), swarm_steps=2,
        neighbour_sweep=(1, 3), sweep_n=20, isolate=False, replay_duration=2.0, estimators=("dekf",), runs=1,
    )  # fmt: skip
    monkeypatch.setattr(bench_command, "QUICK", tiny)  # the preset the command line reads
    rates = B.machine_rates
    monkeypatch.setattr(B, "machine_rates", lambda *a, **k: rates(1, 32, 1, single_thread=False))
    data = ["--mrclam", str(mrclam_root_if_expected)] if mrclam_root_if_expected else []  # section d without it
    assert main(["bench", "--quick", "--json", "--quiet", "--runs", "2", *data]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["config"]["runs"] == 2 and res["fusion_step"]["backends"]["numba"]["runs"] == 2  # --runs over --quick
    assert set(res) == {"machine", "config", "fusion_step", "swarms", "mrclam"}
    assert res["config"]["engine_n"] == 20
    text = format_report(res)
    for heading in ("a. fusion step", "b. machine", "c. swarms", "d. MRCLAM replay", "median of 2,", "load average"):
        assert heading in text
