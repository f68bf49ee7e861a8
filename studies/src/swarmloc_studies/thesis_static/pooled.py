"""Tables 5.1/5.2 over many seeds, against the thesis' own sampling error (``swarmloc-studies reproduce tables``).

The thesis printed one mean deviation (5.10) per number of measurements ``n``, each from 60 repetitions. Such a
mean carries a standard error of ``sd / sqrt(60)`` (``sd``: the standard deviation of one repetition's deviation),
so a comparison with it is only meaningful at that resolution. :func:`pooled_tables` runs the same trials as
:func:`~swarmloc_studies.thesis_static.run_tables` (order-2 fusion) for ``seeds`` seeds of ``reps``
repetitions in parallel, pools every repetition, and reports per ``n``: our mean and its standard error, the
spread of the per-seed means, the thesis' sampling error, and the difference in units of the combined standard
error ``z = (ours - thesis) / sqrt(se_ours^2 + se_60^2)``. A joint chi-square test of all printed values of a
table (the repetitions' covariance across ``n`` estimated from ours) says whether the differences together exceed
sampling error.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.stats import chi2

from swarmloc.experiments.output import write_summary
from swarmloc.experiments.thesis_demo.spec import COMMANDS, SIGMA_M, THESIS_DRIVE
from swarmloc.runner.fanout import fan_out
from swarmloc_studies.thesis_static.run import table_trials
from swarmloc_studies.thesis_static.spec import THESIS_TABLES, deviation_510

if TYPE_CHECKING:
    from distributed import Client

THESIS_REPS = 60


def deviations(seed: int, reps: int, n_max: int = 6) -> dict[str, np.ndarray]:
    """Per motion, the deviation (5.10) of every repetition, ``(n_max, reps)``, order-2 fusion, for ``seed`` (the same
    random streams as ``run_tables(reps=reps, seed=seed)``)."""
    out = {}
    for cmd, ss in zip(COMMANDS, np.random.SeedSequence(seed).spawn(len(COMMANDS)), strict=True):
        _, g_i, posteriors = table_trials(cmd, THESIS_DRIVE, SIGMA_M, n_max, reps, np.random.default_rng(ss))
        out[cmd.name] = np.stack([deviation_510(g_i, posteriors(n, 2).mean) for n in range(1, n_max + 1)])
    return out


def _job(args: tuple[int, int]) -> dict[str, np.ndarray]:
    return deviations(*args)


def pooled_tables(
    out_dir: str | Path,
    seeds: int = 20,
    reps: int = 20_000,
    first_seed: int = 100,
    workers: int | None = None,
    cluster: str | Client | None = None,
) -> dict[str, Any]:
    """Pool ``seeds x reps`` repetitions per motion and compare with the thesis (module docstring); writes
    ``pooled.json`` and ``pooled.md`` into ``out_dir`` and returns the dictionary. The seeds run in ``workers``
    processes (default ``min(2, cpu count)``) or on a Dask ``cluster`` (:func:`~swarmloc.runner.fanout.fan_out`)."""
    if seeds < 2 or reps < 2:
        raise ValueError(f"pooled_tables: need seeds >= 2 and reps >= 2, got {seeds} and {reps}")
    t0 = time.perf_counter()
    workers = workers or max(1, min(2, os.cpu_count() or 1))
    jobs = [(first_seed + s, reps) for s in range(seeds)]
    done = dict(fan_out(_job, [(j,) for j in jobs], jobs=workers, cluster=cluster))
    runs = [done[i] for i in range(len(jobs))]
    result: dict[str, Any] = {
        "command": f"swarmloc-studies reproduce tables --seeds {seeds} --reps {reps} --first-seed {first_seed}",
        "seeds": [s for s, _ in jobs],
        "reps_per_seed": reps,
        "thesis_reps": THESIS_REPS,
        "motions": {},
    }
    for name in runs[0]:
        dev = np.concatenate([r[name] for r in runs], axis=1)  # (n, seeds * reps)
        seed_means = np.stack([r[name].mean(axis=1) for r in runs])  # (seeds, n)
        N = dev.shape[1]
        mean, sd = dev.mean(axis=1), dev.std(axis=1, ddof=1)
        se, se60 = sd / np.sqrt(N), sd / np.sqrt(THESIS_REPS)
        thesis = THESIS_TABLES[name]["mean_deviation"]
        rows = []
        for i in range(dev.shape[0]):
            row: dict[str, Any] = {
                "n": i + 1, "mean": float(mean[i]), "se": float(se[i]), "sd_one_rep": float(sd[i]),
                "seed_mean_min": float(seed_means[:, i].min()), "seed_mean_max": float(seed_means[:, i].max()),
                "seed_mean_sd": float(seed_means[:, i].std(ddof=1)), "seed_means": seed_means[:, i].tolist(),
                "se_thesis_60": float(se60[i]), "thesis": thesis[i],
            }  # fmt: skip
            if thesis[i] is not None:
                se_c = float(np.hypot(se[i], se60[i]))
                d = float(mean[i] - thesis[i])
                row.update(diff=d, rel=d / thesis[i], z=d / se_c, within_2se=abs(d) <= 2 * se_c)
            rows.append(row)
        idx = [i for i in range(len(thesis)) if thesis[i] is not None]
        d = mean[idx] - np.array([thesis[i] for i in idx])
        V = np.cov(dev[idx]) * (1 / THESIS_REPS + 1 / N)  # thesis rows share repetitions, as ours do
        stat = float(d @ np.linalg.solve(V, d))
        result["motions"][name] = {
            "table": THESIS_TABLES[name]["table"],
            "rows": rows,
            "joint": {"chi2": stat, "dof": len(idx), "p": float(chi2.sf(stat, len(idx)))},
        }
    result["runtime_s"] = time.perf_counter() - t0
    write_summary(out_dir, "pooled", result, markdown(result), indent=1)
    return result


def markdown(result: dict[str, Any]) -> str:
    """The pooled comparison as Markdown tables, one per motion."""
    n_all = len(result["seeds"]) * result["reps_per_seed"]
    lines = [
        f"# Thesis Tables 5.1/5.2 over {len(result['seeds'])} seeds x {result['reps_per_seed']} repetitions "
        f"({n_all} per motion), order-2 fusion",
        "",
        f"`{result['command']}` ({result['runtime_s']:.0f} s). se: standard error of our mean; se(60): the thesis' "
        "sampling error with 60 repetitions; z: (ours - thesis) / sqrt(se^2 + se(60)^2).",
        "",
    ]
    for name, m in result["motions"].items():
        lines += [
            f"## {name} (Table {m['table']})",
            "",
            "| n | ours | se | per-seed means | se(60) | thesis | diff | z | within 2 se |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for r in m["rows"]:
            th = "-" if r["thesis"] is None else f"{r['thesis']:.4f}"
            tail = (
                "- | - | -"
                if r["thesis"] is None
                else (f"{100 * r['rel']:+.1f}% | {r['z']:+.2f} | {'yes' if r['within_2se'] else 'no'}")
            )
            lines.append(
                f"| {r['n']} | {r['mean']:.4f} | {r['se']:.5f} | {r['seed_mean_min']:.4f}-{r['seed_mean_max']:.4f} "
                f"| {r['se_thesis_60']:.4f} | {th} | {tail} |"
            )
        j = m["joint"]
        lines += ["", f"All printed values together: chi2 = {j['chi2']:.1f} on {j['dof']} dof, p = {j['p']:.2g}.", ""]
    return "\n".join(lines) + "\n"
