"""Figures of the landmarks-off diagnosis from ``benchmarks/nolm_diagnosis.py``'s JSON files.

    python benchmarks/nolm_diagnosis.py --datasets 9 --out diekf.json
    python benchmarks/nolm_diagnosis.py --datasets 9 --estimator dr --out dr.json
    python benchmarks/nolm_diagnosis.py --windows 150 --datasets 9,3,2,4,1,6 --out win.json [--config odocal.toml]
    python benchmarks/nolm_figures.py --heading diekf.json dr.json --windows win.json win_odocal.json --out figs

``heading.png``: each robot's heading error against its own landmark snapshots over time, with the belief's 2-sigma,
for each run given (dataset 9). ``windows.png``: the truth-free score of every 300 s window per dataset, one marker
per configuration given, the band [0.5, 2] shaded.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def heading(files: list[Path], out: Path, dataset: str) -> None:
    fig, axes = plt.subplots(len(files), 1, figsize=(9, 3.2 * len(files)), sharex=True, squeeze=False)
    for ax, f in zip(axes[:, 0], files, strict=True):
        a = np.array(json.loads(f.read_text())[dataset]["snapshots"]["series"])
        t0 = a[:, 1].min()
        for r in np.unique(a[:, 0]):
            m = a[:, 0] == r
            line = ax.plot(a[m, 1] - t0, a[m, 2], ".", ms=3, label=f"robot {int(r)}")[0]
            ax.plot(a[m, 1] - t0, 2 * a[m, 3], "-", lw=0.6, color=line.get_color())
            ax.plot(a[m, 1] - t0, -2 * a[m, 3], "-", lw=0.6, color=line.get_color())
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel("heading error [rad]")
        ax.set_title(f"{f.stem}: dataset {dataset}, landmarks off, error vs own snapshots (dots), +-2 sigma (lines)")
    axes[-1, 0].set_xlabel("time since the truth-free start [s]")
    axes[0, 0].legend(fontsize=7, ncol=5)
    fig.tight_layout()
    fig.savefig(out / "heading.png", dpi=110)


def windows(files: list[Path], out: Path) -> None:
    fig, ax = plt.subplots(figsize=(8, 4))
    for n, f in enumerate(files):
        d = json.loads(f.read_text())
        for i, k in enumerate(sorted(d, key=int)):
            s = [w["score"] for w in d[k]]
            x = i + 0.15 * (n - (len(files) - 1) / 2) + np.linspace(-0.05, 0.05, len(s))
            ax.plot(x, s, "o^sd"[n % 4], ms=4, color=f"C{n}", label=f.stem if i == 0 else None)
        ax.set_xticks(range(len(d)), [f"dataset {k}" for k in sorted(d, key=int)])
    ax.axhspan(0.5, 2.0, color="0.9")
    ax.set_yscale("log")
    ax.set_ylabel("held-out NIS ratio (landmarks off)")
    ax.set_title("every 300 s window (stride 150 s), diekf, from its own truth-free start")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "windows.png", dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--heading", type=Path, nargs="*", default=[])
    ap.add_argument("--dataset", default="9")
    ap.add_argument("--windows", type=Path, nargs="*", default=[])
    ap.add_argument("--out", type=Path, default=Path("nolm_figures"))
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    if a.heading:
        heading(a.heading, a.out, a.dataset)
    if a.windows:
        windows(a.windows, a.out)


if __name__ == "__main__":
    main()
