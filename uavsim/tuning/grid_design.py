"""Building the inner class grids (attitude, altitude): ``Omega`` levels spaced by J.

In the J convention of this project (processes gain-normalized at their MRFT
phase, rule controllers) a class's controller depends only on its MRFT frequency
``Omega``, so J between two processes is a function of ``Omega_i / Omega_j`` (and
weakly of the true process's shape): J = 1 exactly between processes of equal
``Omega``. The grid is therefore spaced by J along ``Omega`` and spread over the
rest of the box for identification coverage:

1. Sample the box uniformly in log coordinates (seeded) and compute ``Omega``.
2. Calibrate the ratio ``r`` between neighbouring ``Omega`` levels so that the
   median symmetric ``J_(ij)`` of processes ``r`` apart is the target (1.10).
3. Cut ``[Omega_min, Omega_max]`` into geometric bands of ratio ``r``; a class
   level sits at each band's centre.
4. Share the class budget among levels in proportion to the box volume of
   their band (at least one each), and spread each level's classes over its
   iso-``Omega`` surface by k-means (log-box coordinates) on sample points in a
   thin slab around the level.

A lateral grid is built by ``uavsim.tuning.lateral_grid`` (``build_grid`` hands it over).

    from uavsim.tuning.grid_design import build_grid
    g = build_grid("attitude", seed=0)     # unsaved Grid; uavsim.tuning.grid.save_grid writes it
"""

from __future__ import annotations

import datetime as _dt
import math
import time
from typing import Any

import numpy as np

from uavsim.lumped.params import LumpedParams, loop_family
from uavsim.lumped.simulate import fourier_limit_cycle
from uavsim.tuning.grid import (
    BOX_AXES,
    GRID_VERSION,
    TARGETS,
    Grid,
    class_omega,
    class_process_params,
    log_box,
)
from uavsim.tuning.jmatrix import ise_normalized, j_matrix
from uavsim.tuning.rule import DEFAULT_BETA, DEFAULT_PM_DEG, TuningRule

__all__ = ["build_grid"]


#: Omega ratios at which the J curves of the level calibration are sampled
_RATIOS = np.exp(np.linspace(0.01, 0.6, 25))


def _j_curves(fam: str, X: np.ndarray, w: np.ndarray, c1: float, c3: float, att) -> np.ndarray:
    """Symmetric J of each process X (P, d) against rule controllers ``r`` apart in Omega, (P, R).

    Entry ``[j, k]`` is ``max(J(C(w_j r_k), G_j), J(C(w_j / r_k), G_j))`` for ``r_k`` in ``_RATIOS``.
    """
    ctrl = np.concatenate([w[:, None] * _RATIOS[None, :], w[:, None] / _RATIOS[None, :]], axis=1)  # (P, 2R)
    Js = np.empty((len(w), len(_RATIOS)))
    for j in range(len(w)):
        Q, own = ise_normalized(fam, w[j:j + 1], ctrl[j], c1, c3, include_own=True, **class_process_params(fam, X[j:j + 1], att))
        Jj = np.clip(Q[:, 0] / own[0], 1.0, 1e3)
        Js[j] = np.maximum(Jj[: len(_RATIOS)], Jj[len(_RATIOS):])
    return Js


def _calibrate_ratio(fam: str, X: np.ndarray, w: np.ndarray, c1: float, c3: float, target: float, att) -> float:
    """Omega ratio r whose median symmetric J (processes r apart) equals ``target``."""
    med = np.median(_j_curves(fam, X, w, c1, c3, att), axis=0)
    return float(np.exp(np.interp(math.log(target), np.log(med), np.log(_RATIOS))))


def _kmeans(Z: np.ndarray, k: int, rng: np.random.Generator, iters: int = 50) -> np.ndarray:
    """Indices of k points of Z (P, d) nearest to k-means centroids (k-means++ seeding)."""
    if k >= len(Z):
        return np.arange(len(Z))
    C = [Z[rng.integers(len(Z))]]
    for _ in range(1, k):
        d2 = np.min(((Z[:, None, :] - np.array(C)[None]) ** 2).sum(-1), axis=1)
        C.append(Z[rng.choice(len(Z), p=d2 / d2.sum())])
    C = np.array(C)
    for _ in range(iters):
        lab = np.argmin(((Z[:, None, :] - C[None]) ** 2).sum(-1), axis=1)
        C = np.array([Z[lab == c].mean(0) if np.any(lab == c) else C[c] for c in range(k)])
    idx = np.argmin(((Z[:, None, :] - C[None]) ** 2).sum(-1), axis=0)
    return np.unique(idx)


def _design(fam: str, n_target: int, rule: TuningRule, rng: np.random.Generator, n_samples: int,
            target_J: float, n_calib: int = 40) -> dict[str, Any]:
    """Sample the box, place the Omega levels and pick the classes (module docstring, steps 1-4)."""
    c1, c3 = rule.constants
    lo, hi = log_box(fam)
    U = rng.random((n_samples, len(lo)))
    X = np.exp(lo + (hi - lo) * U)
    w = class_omega(fam, X, rule.beta, None)
    ok = np.isfinite(w)
    U, X, w = U[ok], X[ok], w[ok]
    r = _calibrate_ratio(fam, X[:n_calib], w[:n_calib], c1, c3, target_J, None)
    z, unit = np.log(w), math.log(r)
    zmin, zmax = z.min(), z.max()
    n_lev = max(1, int(math.ceil((zmax - zmin) / unit - 1e-9)))
    step = (zmax - zmin) / n_lev  # <= unit: levels exactly tile the range
    band = np.minimum(((z - zmin) / step).astype(int), n_lev - 1)
    vol = np.bincount(band, minlength=n_lev).astype(float)
    # budget: at least one class per level, the rest in proportion to band volume
    extra = max(n_target - n_lev, 0)
    share = vol / vol.sum() * extra
    alloc = 1 + np.floor(share).astype(int)
    rem = extra - (alloc - 1).sum()
    alloc[np.argsort(-(share - np.floor(share)))[:rem]] += 1
    chosen, levels = [], []
    for lev in range(n_lev):
        centre = zmin + (lev + 0.5) * step
        slab = np.nonzero(np.abs(z - centre) < 0.1 * step)[0]
        if len(slab) < 3 * alloc[lev]:
            slab = np.nonzero(band == lev)[0]
        idx = slab[_kmeans(U[slab], int(alloc[lev]), rng)]
        chosen.extend(idx.tolist())
        levels.extend([lev] * len(idx))
    chosen = np.array(chosen)
    # level_step: the Omega ratio between adjacent levels
    return {"X": X[chosen], "level": np.array(levels), "ratio": r, "n_levels": n_lev, "level_step": math.exp(step),
            "omega_range": [float(w.min()), float(w.max())]}


def _finish(fam: str, design: dict, rule: TuningRule, built: dict) -> Grid:
    X = design["X"]
    c1, c3 = rule.constants
    pp = class_process_params(fam, X, None)
    g = rule.gains_batch(fam, K=1.0, **pp)
    J = j_matrix(fam, g["omega"], c1, c3, **pp)
    w_ex, a_ex = np.empty(len(X)), np.empty(len(X))
    for i in range(len(X)):
        p = LumpedParams("roll" if fam == "attitude" else "altitude", 1.0, float(X[i, 0]), float(X[i, 1]), float(X[i, 2]))
        T, a = fourier_limit_cycle(p, rule.beta, 1.0)
        w_ex[i], a_ex[i] = 2 * np.pi / T, a
    params = {k: X[:, i] for i, k in enumerate(BOX_AXES[fam])}
    return Grid(loop=fam, version=GRID_VERSION, params=params, kp=g["kp"], kd=g["kd"],
                derivative_filter_hz=g["derivative_filter_hz"], omega=w_ex, amplitude=a_ex, omega_df=g["omega"], J=J,
                beta=rule.beta, pm_deg=rule.pm_deg, c1=c1, c3=c3, built=built, level=design["level"])


def build_grid(loop: str, beta: float = DEFAULT_BETA, pm_deg: float = DEFAULT_PM_DEG, seed: int = 0,
               n_target: int | None = None, target_J: float = TARGETS["J"], log=None) -> Grid:
    """Build the grid of a loop family (see module docstring). Returns an unsaved ``Grid``.

    A lateral grid is ``uavsim.tuning.lateral_grid.build_lateral`` (its own beta per attitude
    class; ``beta``, ``pm_deg``, ``n_target`` and ``target_J`` are the inner grids').
    """
    from uavsim import __version__ as tool_version

    fam = loop_family(loop)
    if fam == "lateral":
        from uavsim.tuning.lateral_grid import build_lateral

        return build_lateral(seed=seed, log=log)
    rule = TuningRule(beta, pm_deg)
    _ = rule.constants  # validates
    rng = np.random.default_rng(seed)
    t0 = time.time()
    built: dict[str, Any] = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "tool_version": tool_version,
                             "seed": seed, "target_J": target_J, "method": "omega levels spaced by J + k-means on iso-Omega slabs"}
    n_target = n_target or TARGETS[fam]
    d = _design(fam, n_target, rule, rng, 40000, target_J)
    built.update(n_target=n_target, level_ratio=d["ratio"], n_levels=d["n_levels"], level_step=d["level_step"],
                 omega_range=d["omega_range"])
    g = _finish(fam, d, rule, built)
    built["build_time_s"] = round(time.time() - t0, 1)
    return g
