"""Output of the thesis sec. 5.1 demo: Markdown and rich tables, JSON files and the matplotlib figures (matplotlib and
rich are imported only here, inside the functions that use them). The table and JSON helpers also write the
research studies' Tables 5.1/5.2."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.experiments.output import save_figure
from swarmloc.experiments.thesis_demo.spec import CHI2_2_95, SIGMA_M, Command
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.motion import DiffDrive, increment_mean


def console(progress: bool) -> Any:
    """A rich console that prints the progress lines and tables, silent unless ``progress``."""
    from rich.console import Console

    return Console(quiet=not progress, highlight=False, markup=False, width=150)


def jsonable(obj: Any) -> Any:
    """``obj`` in plain Python types for JSON: arrays as lists, numpy scalars as Python ones, non-finite as None."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.floating | float):
        return None if not np.isfinite(obj) else float(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def _fmt(x: Any, digits: int = 4) -> str:
    if x is None:
        return "-"
    if isinstance(x, float | np.floating):
        return f"{x:.{digits}f}"
    return str(x)


def md_table(header: list[str], rows: list[list[Any]]) -> str:
    """A Markdown table; floats with 4 decimals, None as '-'."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_fmt(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def rich_table(title: str, header: list[str], rows: list[list[Any]]) -> Any:
    """The same table for a rich console."""
    from rich.table import Table

    t = Table(title=title)
    for i, h in enumerate(header):
        t.add_column(h, justify="left" if i == 0 else "right")
    for r in rows:
        t.add_row(*(_fmt(c) for c in r))
    return t


# ---------------------------------------------------------------------------------------------- figures
def _ellipse_xy(mean: np.ndarray, cov: np.ndarray, q: float = CHI2_2_95, n: int = 200) -> np.ndarray:
    w, V = np.linalg.eigh(cov)
    t = np.linspace(0, 2 * np.pi, n)
    circ = np.stack([np.cos(t), np.sin(t)], axis=-1) * np.sqrt(q * w)
    return mean + circ @ V.T


def _largest(lines: list[np.ndarray]) -> np.ndarray:
    return max(lines, key=len) if lines else np.zeros((0, 2))


def _poly_area(p: np.ndarray) -> float:
    if len(p) < 3:
        return 0.0
    x, y = p[:, 0], p[:, 1]
    return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _inside(poly: np.ndarray, pts: np.ndarray) -> float:
    from matplotlib.path import Path as MPath

    if len(poly) < 3:
        return float("nan")
    return float(np.mean(MPath(poly).contains_points(pts)))


def _commanded_path(cmd: Command, drive: DiffDrive, start: np.ndarray, n: int = 100) -> np.ndarray:
    h = drive.twist(cmd.w1, cmd.w2)
    ts = np.linspace(0.0, cmd.T, n)
    return SE2.to_xytheta(start @ increment_mean(h, ts))[:, :2]


def _draw_pose(ax: Any, g: np.ndarray, color: str, marker: str, label: str | None, size: float = 60) -> None:
    x, y, th = SE2.to_xytheta(g)
    ax.scatter([x], [y], c=color, marker=marker, s=size, zorder=5, label=label, edgecolors="k", linewidths=0.5)
    ax.quiver([x], [y], [np.cos(th)], [np.sin(th)], color=color, scale=12, width=0.005, zorder=5)


_CONTOUR_KW = {"grid": 121, "n_theta": 91}
_CONTOUR_KW_SMALL = {"grid": 91, "n_theta": 71}


def write_demo(out_dir: Path, result: dict[str, Any], con: Any) -> None:
    """Write ``demo.md`` and ``demo.json`` for the ``result`` of :func:`~swarmloc.experiments.thesis_demo.run_demo`
    (``runtime_s`` set), put both files at the front of ``result["files"]`` and print the table on ``con``."""
    s, cases, files = result["settings"], result["cases"], result["files"]
    seed, noise_scale, n_samples, n_reference = s["seed"], s["noise_scale"], s["n_samples"], s["n_reference"]
    n_importance = s["n_importance"]
    header, rows = _demo_rows(cases)
    md = ["# Thesis sec. 5.1 demo: prior vs fused posterior (robot i, 3 neighbours)", ""]
    md += [
        f"seed {seed}, {n_samples} SDE samples per robot, importance sampling with {n_importance} draws, "
        f"noise scale {noise_scale} (D = {s['D']:g}).",
        "",
    ]
    md += [md_table(header, rows), ""]
    md += [
        "log err = |log(g_true^-1 mu)|; cov err = relative Frobenius error of the covariance: prior vs the second "
        f"moment of log(mu^-1 g) over the {n_samples} SDE samples (in brackets: over {n_reference} samples), "
        "posteriors vs the importance-sampling posterior (IS row: its own Monte Carlo "
        "standard error, from two independent halves); offset IS = |log(mu_IS^-1 mu)|; IS ESS = effective sample "
        "size of each half (below a few hundred the IS reference itself is uncertain by ~10%).",
        "",
    ]
    md += [
        "Prediction vs the SDE: mean NEES of the reference samples under the prior (ideal 3; fraction inside the "
        "95% bound in brackets):",
        "",
    ]
    for name, c in cases.items():
        pv = c["prior_vs_sde"]
        md += [
            f"- {name}: thesis closed form (5.4) {pv['thesis_closed_form']['mean_nees']:.2f} "
            f"({pv['thesis_closed_form']['frac_in_95']:.3f}); second order, 10 sub-steps "
            f"{pv['second_order_10_substeps']['mean_nees']:.2f} ({pv['second_order_10_substeps']['frac_in_95']:.3f})"
        ]
    md += [""]
    sm_txt = np.array2string(SIGMA_M, separator=", ", max_line_width=200).replace("\n", "")
    md += [f"Sigma_m (upper triangle of the printed matrix): {sm_txt}", ""]
    md += [f"runtime {result['runtime_s']:.1f} s", ""]
    reading = how_to_read(cases)
    md[2:2] = [*reading, ""]
    (out_dir / "demo.md").write_text("\n".join(md))
    files[:0] = [str(out_dir / "demo.json"), str(out_dir / "demo.md")]
    (out_dir / "demo.json").write_text(json.dumps(jsonable(result), indent=1))
    con.print(rich_table(f"Thesis 5.1 demo (seed {seed})", header, rows))
    con.print("\n".join(reading))


def how_to_read(cases: dict[str, Any]) -> list[str]:
    """How to read the demo's table: which row is the thesis' method, what "better" means, and, per case, which
    order the numbers favour (said as they are, whichever way they go)."""
    lines = [
        "How to read it: the thesis' method is the row 'posterior, order 2' (second-order fusion, eqs. 3.22-3.28); "
        "'posterior, order 1' drops the second-order terms. The yardstick is the 'IS posterior' row, the exact "
        "posterior up to its Monte Carlo error (+-): the better posterior has the smaller 'offset IS' (distance of "
        "its mean from the IS mean, in exponential coordinates) and the smaller 'cov err' (relative error of its "
        "covariance against the IS covariance). 'log err', 'pos err', 'head err' and 'NEES' compare with one random "
        "true pose, so one seed says little there."
    ]
    for name, c in cases.items():
        q2, q1 = c["posterior_order2"], c["posterior_order1"]
        m2, m1 = q2["mean_offset_vs_importance"], q1["mean_offset_vs_importance"]
        c2, c1 = q2["cov_rel_error_vs_importance"], q1["cov_rel_error_vs_importance"]
        mean_w = "order 2" if m2 < m1 else "order 1"
        cov_w = "order 2" if c2 < c1 else "order 1"
        lines.append(f"{name}: mean closer to IS with {mean_w} (offset {m2:.4f} vs {m1:.4f}), covariance closer "
                     f"with {cov_w} (cov err {c2:.3f} vs {c1:.3f}).")  # fmt: skip
    return lines


def _demo_rows(cases: dict[str, Any]) -> tuple[list[str], list[list[Any]]]:
    header = ["case", "estimate", "log err", "pos err [m]", "head err [rad]", "NEES", "cov err", "offset IS", "IS ESS"]
    rows: list[list[Any]] = []
    for name, c in cases.items():
        p = c["prior"]
        rows.append([
            name, "prior", p["log_error"], p["position_error_m"], p["heading_error_rad"], p["nees"],
            f"{p['cov_rel_error_vs_samples']:.3f} ({p['cov_rel_error_vs_reference_samples']:.3f})", None, None,
        ])  # fmt: skip
        for o in (2, 1):
            q = c[f"posterior_order{o}"]
            rows.append([
                name, f"posterior, order {o}", q["log_error"], q["position_error_m"], q["heading_error_rad"],
                q["nees"], f"{q['cov_rel_error_vs_importance']:.3f}", q["mean_offset_vs_importance"], None,
            ])  # fmt: skip
        s = c["importance"]
        rows.append([
            name, "IS posterior", s["log_error"], s["position_error_m"], s["heading_error_rad"], s["nees"],
            f"+-{s['cov_rel_std_error']:.3f}", f"+-{s['mean_std_error']:.4f}",
            " + ".join(f"{e:.0f}" for e in s["ess"]),
        ])  # fmt: skip
    return header, rows


def demo_figures(
    out_dir: Path,
    cmd: Command,
    drive: DiffDrive,
    starts: np.ndarray,
    samples: np.ndarray,
    truth: np.ndarray,
    beliefs: list[GroupGaussian],
    post: dict[int, GroupGaussian],
    is_gauss: GroupGaussian,
    noise_scale: float,
    files: list[str],
) -> dict[str, float]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    prior = beliefs[0]
    xy_i = SE2.to_xytheta(samples[:, 0])[:, :2]
    exp_c = _largest(prior.xy_contour(0.95, **_CONTOUR_KW))
    cart_c = _ellipse_xy(xy_i.mean(axis=0), np.cov(xy_i.T))
    info = {
        "exp_contour_coverage": _inside(exp_c, xy_i),
        "exp_contour_area_m2": _poly_area(exp_c),
        "cartesian_ellipse_coverage": _inside(cart_c, xy_i),
        "cartesian_ellipse_area_m2": _poly_area(cart_c),
    }
    title = f"{cmd.name}: T = {cmd.T:g} s, D = {drive.D:g}"

    # --- figure 5.2 / 5.3: prediction only
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    ax.scatter(xy_i[:, 0], xy_i[:, 1], s=4, c="tab:cyan", alpha=0.6, label=f"{len(xy_i)} SDE end poses")
    path = _commanded_path(cmd, drive, starts[0])
    ax.plot(path[:, 0], path[:, 1], "b--", lw=1.2, label="commanded path")
    ax.plot(path[[0, -1], 0], path[[0, -1], 1], "bo", ms=5)
    ax.plot(exp_c[:, 0], exp_c[:, 1], "m-", lw=2,
            label=f"95% exp.-coord. Gaussian (covers {info['exp_contour_coverage']:.0%}, "
            f"{info['exp_contour_area_m2']:.3f} m$^2$)")  # fmt: skip
    ax.plot(cart_c[:, 0], cart_c[:, 1], "g--", lw=1.5,
            label=f"95% Cartesian ellipse of samples (covers {info['cartesian_ellipse_coverage']:.0%}, "
            f"{info['cartesian_ellipse_area_m2']:.3f} m$^2$)")  # fmt: skip
    _draw_pose(ax, prior.mean, "m", "o", "prior mean")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"Prediction only ({title})")
    ax.legend(fontsize=7, loc="best")
    files.append(save_figure(fig, out_dir / f"demo_prediction_{cmd.name}.png", dpi=120))

    # --- figure 5.4 / 5.5: fusion
    fig, ax = plt.subplots(figsize=(9.5, 6.5))
    for k in range(len(beliefs)):
        p = _commanded_path(cmd, drive, starts[k])
        ax.plot(p[:, 0], p[:, 1], "b--", lw=1, label="commanded paths" if k == 0 else None)
        ax.plot(p[[0, -1], 0], p[[0, -1], 1], "bo", ms=4)
    for k in range(1, len(beliefs)):
        xy = SE2.to_xytheta(samples[:, k])[:, :2]
        ax.scatter(xy[:, 0], xy[:, 1], s=3, c="gold", alpha=0.35, label="neighbours' SDE samples" if k == 1 else None)
        c = _largest(beliefs[k].xy_contour(0.95, **_CONTOUR_KW_SMALL))
        ax.plot(c[:, 0], c[:, 1], color="orange", lw=1.2, label="neighbours' beliefs (95%)" if k == 1 else None)
        _draw_pose(ax, truth[k], "r", "o", "true poses" if k == 1 else None, size=30)
    ax.scatter(xy_i[:, 0], xy_i[:, 1], s=3, c="tab:cyan", alpha=0.35, label="robot i's SDE samples")
    ax.plot(exp_c[:, 0], exp_c[:, 1], "m-", lw=1.8, label="robot i prior (95%)")
    c2 = _largest(post[2].xy_contour(0.95, **_CONTOUR_KW))
    c1 = _largest(post[1].xy_contour(0.95, **_CONTOUR_KW))
    cis = _largest(is_gauss.xy_contour(0.95, **_CONTOUR_KW))
    ax.plot(c2[:, 0], c2[:, 1], "k-", lw=2, label="posterior, 2nd order (95%)")
    ax.plot(c1[:, 0], c1[:, 1], color="0.45", ls="--", lw=1.5, label="posterior, 1st order (95%)")
    ax.plot(cis[:, 0], cis[:, 1], color="tab:green", ls=":", lw=2, label="importance-sampling posterior (95%)")
    _draw_pose(ax, prior.mean, "m", "o", "prior mean", size=40)
    _draw_pose(ax, truth[0], "r", "*", "robot i true pose", size=150)
    _draw_pose(ax, post[2].mean, "k", "o", "posterior mean (2nd order)", size=40)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"Fusion of 3 relative measurements ({title})")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    files.append(save_figure(fig, out_dir / f"demo_fusion_{cmd.name}.png", dpi=120))
    return info
