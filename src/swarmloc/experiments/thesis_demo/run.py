"""Computations of the thesis sec. 5.1 demo: :func:`run_demo` (figures 5.2-5.5) builds its result dictionary and
hands it to :mod:`swarmloc.experiments.thesis_demo.report`."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.evaluation.montecarlo import group_mean, importance_posterior
from swarmloc.experiments.thesis_demo.report import console, demo_figures, jsonable, write_demo
from swarmloc.experiments.thesis_demo.spec import (
    CHI2_3_95,
    COMMANDS,
    NEIGHBOUR_OFFSETS,
    SIGMA_M,
    SIGMA_M_PRINTED,
    THESIS_DRIVE,
    Command,
    formation,
    pose_errors,
    prediction,
    relative_measurements,
    sample_end_poses,
)
from swarmloc.fusion import fuse_relative
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.motion import DiffDrive


def _rel_frob(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.linalg.norm(A - B) / np.linalg.norm(B))


def _second_moment(y: np.ndarray) -> np.ndarray:
    return y.T @ y / y.shape[0]


def _prior_checks(
    cmd: Command, drive: DiffDrive, starts: np.ndarray, prior: GroupGaussian, Sigma: np.ndarray, samples: np.ndarray,
    n_reference: int, rng_ref: np.random.Generator, n_steps: int,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any], dict[str, dict[str, float]]]:  # fmt: skip
    """Robot ``i``'s prior against the SDE samples it describes: the second moments of ``log(mu^-1 g)`` over
    ``samples`` and over ``n_reference`` extra ones, its :func:`run_demo` stats, and ``prior_vs_sde`` (the mean NEES
    of the extra samples under the closed form and the composed prediction); ``Sigma``: the prior's covariance as
    predicted."""
    cov_s = _second_moment(prior.tangent_of(samples[:, 0], validate=False))
    ref = sample_end_poses(cmd, drive, starts[:1], n_reference, rng_ref, n_steps)[:, 0]
    cov_ref = _second_moment(prior.tangent_of(ref, validate=False))
    gm, _ = group_mean(SE2, samples[:, 0], init=prior.mean)
    prior_vs_sde = {}
    for label, k in (("thesis_closed_form", 1), ("second_order_10_substeps", 10)):
        nees_ref = GroupGaussian(SE2, *prediction(cmd, drive, k), validate=False).mahalanobis2(ref, validate=False)
        prior_vs_sde[label] = {
            "mean_nees": float(nees_ref.mean()),
            "frac_in_95": float(np.mean(nees_ref <= CHI2_3_95)),
        }
    stats = {
        "cov_rel_error_vs_samples": _rel_frob(Sigma, cov_s),
        "cov_rel_error_vs_reference_samples": _rel_frob(Sigma, cov_ref),
        "sample_group_mean_offset": float(np.linalg.norm(prior.tangent_of(gm, validate=False))),
    }
    return cov_s, cov_ref, stats, prior_vs_sde


def _importance_check(
    prior: GroupGaussian, pairs: list[tuple[GroupGaussian, GroupGaussian]], n_importance: int,
    rngs: tuple[np.random.Generator, np.random.Generator],
) -> tuple[GroupGaussian, dict[str, Any]]:  # fmt: skip
    """The importance-sampling posterior: two independent halves of ``n_importance`` draws, averaged, and its
    statistics but the estimate's own (effective sample sizes; half the halves' difference estimates its error)."""
    is_runs = [importance_posterior(prior, pairs, max(1, n_importance // 2), r) for r in rngs]
    d_is = SE2.log(SE2.inverse(is_runs[0][0]) @ is_runs[1][0])
    is_mean = is_runs[0][0] @ SE2.exp(0.5 * d_is)
    is_cov = 0.5 * (is_runs[0][1] + is_runs[1][1])
    stats = {
        "n": n_importance,
        "ess": [float(r[2]) for r in is_runs],
        # standard error of the average of two independent halves ~ half their difference
        "cov_rel_std_error": 0.5 * _rel_frob(is_runs[1][1], is_runs[0][1]),
        "mean_std_error": 0.5 * float(np.linalg.norm(d_is)),
    }
    return GroupGaussian(SE2, is_mean, is_cov, validate=False), stats


def _demo_settings(seed: int, n_samples: int, n_importance: int, n_reference: int, n_steps: int, noise_scale: float,
                   prior_substeps: int, drive: DiffDrive, Sm: np.ndarray, n_nb: int) -> dict[str, Any]:  # fmt: skip
    """The ``settings`` of :func:`run_demo`'s result: its arguments and the choices the text leaves open."""
    return {
        "seed": seed,
        "n_samples": n_samples,
        "n_importance": n_importance,
        "n_reference": n_reference,
        "n_steps": n_steps,
        "noise_scale": noise_scale,
        "prior_substeps": prior_substeps,
        "r": drive.r,
        "l": drive.l,
        "D": drive.D,
        "sigma_m": Sm,
        "sigma_m_printed": SIGMA_M_PRINTED,
        "sigma_m_note": "printed matrix is not symmetric; upper triangle kept (positive definite)",
        "circular_T_note": "text says 'for 1 second', parameter list says T = 2; T = 2 used (quarter circle)",
        "formation": "robot i at the origin heading +x; neighbours at lateral offsets "
        f"{list(NEIGHBOUR_OFFSETS[:n_nb])} m, same heading, same command",
        "fusion": "swarmloc.fuse_relative, iterations=2 (default), order 2 and order 1",
    }


def run_demo(
    out_dir: Path,
    seed: int = 0,
    n_samples: int = 500,
    progress: bool = True,
    *,
    n_importance: int = 200_000,
    n_reference: int = 20_000,
    n_steps: int = 200,
    figures: bool = True,
    noise_scale: float = 1.0,
    prior_substeps: int = 1,
) -> dict:
    """Figures 5.2-5.5 of the thesis with numbers: prior vs fused posterior for a team of four, both motions.

    For each motion (straight, circular): ``n_samples`` SDE end poses per robot (one of them, chosen at random, is
    the truth), robot ``i``'s prior, three relative measurements and the second- and first-order posteriors.
    Reported per estimate: ``|log(g_true^-1 mu)|``, position and heading error, NEES of the truth; the prior
    covariance against the second moment of ``log(mu^-1 g)`` over the ``n_samples`` samples and over
    ``n_reference`` extra samples; each posterior's covariance and mean against an importance-sampling posterior
    (:func:`~swarmloc.evaluation.montecarlo.importance_posterior`, ``n_importance`` draws in two independent halves
    whose moments are averaged; half their difference is reported as its Monte Carlo standard error).

    Keyword-only extras: ``figures=False`` skips the plots (and the contour coverage numbers); ``noise_scale``
    multiplies both ``D`` and ``Sigma_m`` (1 = thesis); ``prior_substeps`` > 1 uses the second-order composed
    prediction of :func:`prediction` for every belief instead of the thesis' closed form. ``prior_vs_sde`` reports
    the mean NEES of the ``n_reference`` SDE samples under both predictions (ideal 3).

    Writes ``demo.json``, ``demo.md`` and, with figures, ``demo_prediction_{straight,circular}.png`` (like Figs
    5.2/5.3) and ``demo_fusion_{straight,circular}.png`` (like Figs 5.4/5.5) to ``out_dir``. Returns the
    dictionary written to ``demo.json`` (plain Python types).
    """
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    con = console(progress)
    drive = DiffDrive(THESIS_DRIVE.r, THESIS_DRIVE.l, THESIS_DRIVE.D * noise_scale)
    Sm = SIGMA_M * noise_scale
    n_nb = 3
    starts = formation(n_nb)
    K = n_nb + 1
    cases: dict[str, Any] = {}
    files: list[str] = []
    for cmd, ss in zip(COMMANDS, np.random.SeedSequence(seed).spawn(len(COMMANDS)), strict=True):
        t_case = time.perf_counter()
        rng_sim, rng_ref, rng_is1, rng_is2 = (np.random.default_rng(s) for s in ss.spawn(4))
        mu_inc, Sigma = prediction(cmd, drive, prior_substeps)
        samples = sample_end_poses(cmd, drive, starts, n_samples, rng_sim, n_steps)  # (n, K, 3, 3)
        pick = rng_sim.integers(n_samples, size=K)
        truth = samples[pick, np.arange(K)]
        meas = relative_measurements(truth, Sm, rng_sim)
        beliefs = [GroupGaussian(SE2, a @ mu_inc, Sigma) for a in starts]
        prior = beliefs[0]
        pairs = [(beliefs[k + 1], GroupGaussian(SE2, meas[k], Sm)) for k in range(n_nb)]
        post = {2: fuse_relative(prior, pairs, order=2), 1: fuse_relative(prior, pairs, order=1)}
        cov_s, cov_ref, prior_stats, prior_vs_sde = _prior_checks(
            cmd, drive, starts, prior, Sigma, samples, n_reference, rng_ref, n_steps
        )
        is_gauss, is_stats = _importance_check(prior, pairs, n_importance, (rng_is1, rng_is2))
        is_mean, is_cov = is_gauss.mean, is_gauss.cov
        g_i = truth[0]
        res: dict[str, Any] = {
            "command": {"w1": cmd.w1, "w2": cmd.w2, "T": cmd.T, "twist": drive.twist(cmd.w1, cmd.w2)},
            "prior": {**_estimate_stats(g_i, prior), **prior_stats},
            "prior_vs_sde": prior_vs_sde,
            "importance": {**_estimate_stats(g_i, is_gauss), **is_stats},
        }
        for o, g in post.items():
            res[f"posterior_order{o}"] = {
                **_estimate_stats(g_i, g),
                "cov_rel_error_vs_importance": _rel_frob(g.cov, is_cov),
                "mean_offset_vs_importance": float(np.linalg.norm(SE2.log(SE2.inverse(is_mean) @ g.mean))),
            }
        means = {"starts": starts, "truth": truth, "measurements": meas, "prior_mean": prior.mean,
                 "posterior_order2_mean": post[2].mean, "posterior_order1_mean": post[1].mean,
                 "importance_mean": is_mean}  # fmt: skip
        res["poses_xytheta"] = {k: SE2.to_xytheta(v) for k, v in means.items()}
        res["covariances"] = {"prior": Sigma, "samples": cov_s, "reference_samples": cov_ref,
                              "posterior_order2": post[2].cov, "posterior_order1": post[1].cov,
                              "importance": is_cov}  # fmt: skip
        if figures:
            res["contours"] = demo_figures(
                out_dir, cmd, drive, starts, samples, truth, beliefs, post, is_gauss, noise_scale, files
            )
        res["runtime_s"] = time.perf_counter() - t_case
        cases[cmd.name] = res
        con.print(f"[demo] {cmd.name}: done in {res['runtime_s']:.1f} s")

    result: dict[str, Any] = {
        "experiment": "thesis sec. 5.1, figures 5.2-5.5 (team of 4: robot i + 3 neighbours)",
        "settings": _demo_settings(
            seed, n_samples, n_importance, n_reference, n_steps, noise_scale, prior_substeps, drive, Sm, n_nb
        ),
        "cases": cases,
        "files": files,
    }
    result["runtime_s"] = time.perf_counter() - t0
    write_demo(out_dir, result, con)
    return jsonable(result)


def _estimate_stats(g_true: np.ndarray, g: GroupGaussian) -> dict[str, float]:
    e = pose_errors(g_true, g.mean)
    return {
        "log_error": float(e["log"]),
        "position_error_m": float(e["position"]),
        "heading_error_rad": float(e["heading"]),
        "nees": float(g.mahalanobis2(g_true, validate=False)),
    }
