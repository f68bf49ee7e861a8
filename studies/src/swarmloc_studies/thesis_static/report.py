"""Output of thesis Tables 5.1/5.2: Markdown and rich tables, JSON files and the matplotlib figures (matplotlib and
rich are imported only here, inside the functions that use them)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.experiments.output import save_figure
from swarmloc.experiments.thesis_demo.report import jsonable, md_table, rich_table


def write_tables(out_dir: Path, result: dict[str, Any], con: Any) -> None:
    """Write ``tables.md`` and ``tables.json`` for the ``result`` of
    :func:`~swarmloc_studies.thesis_static.run_tables` (``runtime_s`` set) and print the tables on ``con``."""
    s, motions = result["settings"], result["motions"]
    reps, seed, noise_scale = s["reps"], s["seed"], s["noise_scale"]
    md = [f"# Thesis Tables 5.1/5.2: {reps} repetitions per n (seed {seed}, noise scale {noise_scale})", ""]
    for name, m in motions.items():
        header, trows = _tables_rows(m)
        md += [f"## {name} (thesis Table {m['thesis']['table']})", "", md_table(header, trows), ""]
        if m["thesis"]["note"]:
            md += [f"Thesis row note: {m['thesis']['note']}.", ""]
        md += [f"mean ||x_true|| = {m['norm_x_true_mean']:.3f}", ""]
        con.print(rich_table(f"{name} (thesis Table {m['thesis']['table']})", header, trows))
    md += [
        "dev = mean deviation (5.10); Frob = Frobenius norm of the average posterior covariance; tr = mean "
        "trace of the posterior covariance; in95 = fraction of runs with NEES <= chi2_3(0.95) = 7.81; "
        "better = fraction of runs where the posterior's |log(g_true^-1 mu)| is below the prior's. "
        "o2/o1 = fusion order. Row n = 0 is the prior.",
        "",
    ]
    md += [f"runtime {result['runtime_s']:.1f} s", ""]
    (out_dir / "tables.md").write_text("\n".join(md))
    (out_dir / "tables.json").write_text(json.dumps(jsonable(result), indent=1))
    con.print(f"[tables] wrote {out_dir} in {result['runtime_s']:.1f} s")


def _tables_rows(m: dict[str, Any]) -> tuple[list[str], list[list[Any]]]:
    header = [
        "n", "dev o2", "dev o1", "dev thesis", "Frob o2", "Frob o1", "Frob thesis", "tr o2",
        "log err o2", "pos err o2", "head err o2", "NEES o2", "in95 o2", "NEES o1", "in95 o1", "better o2",
    ]  # fmt: skip
    p = m["prior"]
    rows: list[list[Any]] = [[
        0, p["mean_deviation"], None, None, p["frobenius_mean_cov"], None, None, p["mean_trace_cov"],
        p["mean_log_error"], p["mean_position_error_m"], p["mean_heading_error_rad"], p["mean_nees"],
        p["frac_nees_in_95"], None, None, None,
    ]]  # fmt: skip
    th = m["thesis"]
    for r2, r1 in zip(m["order2"], m["order1"], strict=True):
        n = r2["n"]
        rows.append([
            n, r2["mean_deviation"], r1["mean_deviation"], th["mean_deviation"][n - 1] if n <= 6 else None,
            r2["frobenius_mean_cov"], r1["frobenius_mean_cov"], th["frobenius_norm"][n - 1] if n <= 6 else None,
            r2["mean_trace_cov"], r2["mean_log_error"], r2["mean_position_error_m"], r2["mean_heading_error_rad"],
            r2["mean_nees"], r2["frac_nees_in_95"], r1["mean_nees"], r1["frac_nees_in_95"],
            r2["frac_better_than_prior"],
        ])  # fmt: skip
    return header, rows


def tables_figures(out_dir: Path, motions: dict[str, Any], reps: int) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    for name, m in motions.items():
        N = len(m["order2"])
        ns = np.arange(1, N + 1)
        fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.5))
        ax.boxplot([m["prior"]["deviations"]], positions=[0], widths=0.3, patch_artist=True,
                   boxprops={"facecolor": "plum"}, medianprops={"color": "k"})  # fmt: skip
        for order, dx, col in ((2, -0.18, "tab:blue"), (1, 0.18, "tab:orange")):
            data = [r["deviations"] for r in m[f"order{order}"]]
            ax.boxplot(data, positions=ns + dx, widths=0.3, patch_artist=True,
                       boxprops={"facecolor": col, "alpha": 0.6}, medianprops={"color": "k"})  # fmt: skip
            ax.plot([], [], "s", color=col, alpha=0.6, label=f"order {order}")
            ax.plot(ns + dx, [r["mean_deviation"] for r in m[f"order{order}"]], "k^", ms=4)
        th = np.array([np.nan if v is None else v for v in m["thesis"]["mean_deviation"][:N]], dtype=float)
        ax.plot(ns, th, "rx", ms=8, mew=2, label="thesis mean")
        ax.plot([], [], "k^", ms=4, label="our mean")
        ax.set_xticks(np.arange(0, N + 1))
        ax.set_xticklabels(["prior", *[str(n) for n in ns]])
        ax.set_xlabel("number of measurements")
        ax.set_ylabel("deviation (5.10)")
        ax.set_title(f"{name}: deviation over {reps} runs (Table {m['thesis']['table']})")
        ax.legend(fontsize=8)
        for order, col in ((2, "tab:blue"), (1, "tab:orange")):
            bx.plot(ns, [r["frobenius_mean_cov"] for r in m[f"order{order}"]], "o-", color=col,
                    label=f"ours, order {order}")  # fmt: skip
        bx.axhline(m["prior"]["frobenius_mean_cov"], color="m", ls=":", label="prior")
        bx.plot(ns, m["thesis"]["frobenius_norm"][:N], "rx--", label="thesis")
        bx.set_xlabel("number of measurements")
        bx.set_ylabel("Frobenius norm of the average posterior covariance")
        bx.set_yscale("log")
        bx.set_title("posterior covariance size")
        bx.legend(fontsize=8)
        files.append(save_figure(fig, out_dir / f"tables_{name}.png"))
    return files
