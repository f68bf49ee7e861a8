"""The text report of ``swarmloc-studies bench`` (:func:`format_report`): one table per section that ran, from the
results of :func:`swarmloc_studies.bench.run_bench` (section e's lines from
:func:`swarmloc_studies.accelerator.format_accelerator`)."""

from __future__ import annotations

__all__ = ["format_report"]


def _fmt_rate(x: float) -> str:
    return f"{x:,.0f}" if x >= 100 else f"{x:.3g}"


def format_report(res: dict) -> str:
    """The results as plain text tables (what ``swarmloc-studies bench`` prints), the sections that ran."""
    m = res["machine"]
    out = [f"machine: {m['platform']}, {m['cpu_count']} cores, python {m['python']}, numpy {m['numpy']}"]
    if "bandwidth_gb_s" in m:
        out += ["", *_format_machine(m)]
    if "fusion_step" in res:
        out += ["", *_format_fusion(res["fusion_step"])]
    if "swarms" in res:
        out += ["", *_format_swarms(res["swarms"])]
    if "mrclam" in res:
        out += ["", *_format_replay(res["mrclam"])]
    if "accelerator" in res:
        from swarmloc_studies.accelerator import format_accelerator

        out += ["", *format_accelerator(res["accelerator"])]
    return "\n".join(out)


def _format_machine(m: dict) -> list[str]:
    one = m.get("gflops_one_thread")
    return [
        "b. machine",
        f"  memory bandwidth (numpy copy of {m['copy_mb']} MB, read + write): {m['bandwidth_gb_s']:.1f} GB/s",
        f"  float64 matmul {m['matmul_n']}^2: {m['gflops']:.1f} GFLOP/s (BLAS threads: {m['blas_threads_env']})"
        + (f", {one:.1f} GFLOP/s on one thread" if one else ""),
    ]


def _format_fusion(f: dict) -> list[str]:
    out = [f"a. fusion step: prediction + {f['neighbours']} relative-pose updates per robot (SE(2) EKF)"]
    rows = [("filterpy EKF, per-robot loop", f["filterpy"])]
    rows += [(f"swarmloc engine, {b}", r) for b, r in f.get("backends", {"numpy": f["engine"]}).items()]
    for label, r in rows:
        if "skipped" in r:
            out.append(f"  {label:<36} skipped: {r['skipped']}")
            continue
        rate = _fmt_rate(r["robot_updates_per_s"])
        ratio = f"  {r['over_filterpy']:,.0f}x filterpy" if "over_filterpy" in r else ""
        spread = ""
        if r.get("runs", 1) > 1:
            lo, hi = r["min_robot_updates_per_s"], r["max_robot_updates_per_s"]
            spread = f"  median of {r['runs']}, {lo:.3g} to {hi:.3g}; {r['robot_updates_per_cpu_s']:.3g} per CPU second"
        out.append(f"  {label:<36} {r['n']:>7,} robots {rate:>12} robot-updates/s{ratio}{spread}")
    loads = [x for r in f.get("backends", {}).values() for x in r.get("load_1min", ())]
    if loads:
        out.append(f"  load average (1 min) around the engine runs: {min(loads):.2f} to {max(loads):.2f}")
    if "fraction_of_bandwidth" in f:
        frac1 = f.get("fraction_of_flops_one_thread")
        out.append(f"  work estimate per robot-update: {f['bytes_per_update']} B, {f['flops_per_update']} flop")
        out.append(
            f"  engine (numpy): {f['achieved_gb_s']:.3f} GB/s = {100 * f['fraction_of_bandwidth']:.2f}% of the "
            "bandwidth, "
            f"{f['achieved_gflops']:.3f} GFLOP/s = {100 * f['fraction_of_flops']:.2f}% of the FLOP rate"
            + (f" ({100 * frac1:.2f}% of one thread's)" if frac1 else "")
        )
    return out


def _format_swarms(s: dict) -> list[str]:
    backend = s.get("by_size", [{}])[0].get("backend", "numpy") if "skipped" not in s else ""
    out = [f"c. swarms (engine, distributed EKF, {backend})"]
    if "skipped" in s:
        return [*out, f"  skipped: {s['skipped']}"]
    cols = ("robots", "nb", "steps", "sim [s]", "est [s]", "us/robot-step", "peak MB")
    widths = (7, 3, 6, 8, 8, 14, 8)
    out.append("  " + " ".join(f"{c:>{w}}" for c, w in zip(cols, widths, strict=True)))
    for r in [*s["by_size"], *[r for r in s["by_neighbours"] if r not in s["by_size"]]]:
        vals = (f"{r['n']:,}", r["neighbours"], r["steps"], f"{r['wall_sim_s']:.2f}", f"{r['wall_est_s']:.2f}",
                f"{r['us_per_robot_step']:.2f}", f"{r['peak_mem_bytes'] / 2**20:.0f}")  # fmt: skip
        out.append("  " + " ".join(f"{v:>{w}}" for v, w in zip(vals, widths, strict=True)))
    out.append(
        f"  log-log slopes: cost per robot vs team size {s['slope_cost_per_robot_vs_size']:+.2f} (wall vs size "
        f"{s['slope_wall_vs_size']:+.2f}), cost per robot vs neighbours "
        f"{s['slope_cost_per_robot_vs_neighbours']:+.2f}"
    )
    src = {r.get("peak_mem_source", "") for r in s["by_size"]}
    out.append(f"  (peak memory: resident, interpreter included; {', '.join(sorted(src))})")
    return out


def _format_replay(d: dict) -> list[str]:
    out = ["d. MRCLAM replay (x real time = replayed seconds / wall seconds of the event loop)"]
    if "skipped" in d:
        return [*out, f"  skipped: {d['skipped']}"]
    out.append(f"  {d['dataset']}, {d['duration_s']:.0f} s, best of {d['rounds']}")
    keys = [k for k in ("landmarks_on", "landmarks_off") if k in d]
    out.append(f"  {'estimator':<12}" + "".join(f"{k.replace('_', ' '):>16}" for k in keys))
    for n in d[keys[0]]["estimators"] if keys else ():
        out.append(f"  {n:<12}" + "".join(f"{d[k]['estimators'][n]['x_real_time']:>15.0f}x" for k in keys))
    engines = [n for n in d[keys[0]]["estimators"] if n.endswith("/engine")] if keys else []
    if engines:
        out.append(f"  ({', '.join(engines)}: through the engine's compiled replay, numba; the whole call timed)")
    return out
