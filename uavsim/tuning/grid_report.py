"""Figures of a class grid: class counts, neighbour J, coverage of random box points, build time.

For the inner grids J is the rule's (``uavsim.tuning.jmatrix``); a lateral grid pools its
sub-grids (``_lateral_report``). The figures of a grid's table at the control rate, against
the ISE optimum, are ``uavsim.tuning.table_report``'s.

    from uavsim.tuning.grid import load_grid
    from uavsim.tuning.grid_report import grid_report
    rep = grid_report(load_grid("altitude"), n_points=2000, seed=1)
    rep["neighbour_J_across_levels"]["mean"], rep["coverage"]["worst_J"]
"""

from __future__ import annotations

from typing import Any

import numpy as np

from uavsim.lumped.params import loop_family
from uavsim.tuning.grid import Grid, box_sample, class_omega, class_process_params, neighbour_pairs
from uavsim.tuning.jmatrix import J_MAX, ise_normalized, symmetrize

__all__ = ["grid_report", "coverage"]


def _stats(x: np.ndarray) -> dict[str, float]:
    if len(x) == 0:
        return {"mean": float("nan"), "min": float("nan"), "max": float("nan"), "n": 0}
    return {"mean": float(np.mean(x)), "min": float(np.min(x)), "max": float(np.max(x)), "n": int(len(x))}


def _point_J(grid: Grid, n_points: int, seed: int) -> tuple[np.ndarray, dict[str, Any]]:
    """Best-class J of seeded random box points, and the stability shares behind it.

    The assignment is the best available class for the point (what an ideal
    J-trained classifier returns): ``min_i J(C_i, G_x)``, over the points whose
    own rule loop is stable (J is a ratio to that loop's ISE). Returns the J of
    those points, (P,), and ``n_sampled``, ``stable_fraction`` (own rule stable)
    and ``assigned_stable_fraction`` (some class controller stabilizes the point,
    own rule stable or not).
    """
    fam = loop_family(grid.loop)
    X = box_sample(fam, np.random.default_rng(seed), n_points)
    att = grid.attitude
    w = class_omega(fam, X, grid.beta, att)
    ok = np.isfinite(w)
    X, w = X[ok], w[ok]
    Q, own = ise_normalized(fam, w, grid.omega_df, grid.c1, grid.c3, include_own=True, **class_process_params(fam, X, att))
    st = np.isfinite(own)
    with np.errstate(invalid="ignore"):
        J = np.clip(np.where(np.isfinite(Q[:, st]), Q[:, st] / own[st], J_MAX), 1.0, J_MAX)  # (n, P) as deterioration()
    info = {"n_sampled": int(len(w)), "stable_fraction": float(st.mean()) if len(w) else float("nan"),
            "assigned_stable_fraction": float(np.isfinite(Q).any(axis=0).mean()) if len(w) else float("nan")}
    return (J.min(axis=0) if J.size else np.zeros(0)), info


def _j_figures(best: np.ndarray) -> dict[str, float]:
    if len(best) == 0:
        return {"n_points": 0, "worst_J": float("nan"), "p99_J": float("nan"), "mean_J": float("nan")}
    return {"n_points": int(len(best)), "worst_J": float(best.max()), "p99_J": float(np.quantile(best, 0.99)),
            "mean_J": float(best.mean())}


def coverage(grid: Grid, n_points: int = 2000, seed: int = 1) -> dict[str, Any]:
    """Worst-case J between random box points and the class each would be assigned (``_point_J``;
    inner grids, the rule's J)."""
    best, _ = _point_J(grid, n_points, seed)
    return _j_figures(best)


def _neighbour_J(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Symmetrized J of the neighbour pairs across and within Omega levels."""
    Js = symmetrize(grid.J)
    across, within = neighbour_pairs(grid)
    return (Js[across[:, 0], across[:, 1]] if len(across) else np.zeros(0),
            Js[within[:, 0], within[:, 1]] if len(within) else np.zeros(0))


def _lateral_report(grid: Grid) -> dict[str, Any]:
    """Figures of a lateral grid pooled over its sub-grids.

    Class counts, each attitude class's relay beta and rule, the neighbour J of the classes
    (``Grid.J``: for the lateral grids the table's J of the robust answers) and the design
    sample's best-class J. The coverage of random box points against each point's own optimum
    at the control rate is in the table's figures (``uavsim.tuning.table_report``).
    """
    nb = np.concatenate([_neighbour_J(s)[0] for s in grid.sub])
    rules: dict[str, int] = {}
    for s in grid.sub:
        key = f"beta {s.beta:g} pm {s.pm_deg:g} scale {s.gain_scale:g}"
        rules[key] = rules.get(key, 0) + 1
    betas = np.array([s.beta for s in grid.sub])
    sample = [s.built.get("sample_best_J", {}).get("max", float("nan")) for s in grid.sub]
    return {
        "loop": grid.loop, "version": grid.version, "hash": grid.hash,
        "n_subgrids": len(grid.sub), "n_classes_total": int(sum(s.n for s in grid.sub)),
        "n_classes_min": int(min(s.n for s in grid.sub)), "n_classes_max": int(max(s.n for s in grid.sub)),
        "neighbour_J": {**_stats(nb), "median": float(np.median(nb)) if len(nb) else float("nan"),
                        "p95": float(np.quantile(nb, 0.95)) if len(nb) else float("nan"),
                        "unstable": int(np.sum(nb >= J_MAX))},
        "beta": {"min": float(betas.min()), "median": float(np.median(betas)), "max": float(betas.max())},
        "rules": "; ".join(f"{k}: {v}" for k, v in sorted(rules.items(), key=lambda kv: -kv[1])),
        "gain_scale_range": [float(min(s.gain_scale for s in grid.sub)), float(max(s.gain_scale for s in grid.sub))],
        "design_sample_best_J_max": float(np.nanmax(sample)) if sample else float("nan"),
        "build_time_s": grid.built.get("build_time_s"), "built": grid.built,
    }


def grid_report(grid: Grid, n_points: int = 2000, seed: int = 1) -> dict[str, Any]:
    """Counts, neighbour-J statistics, coverage and build figures of a grid.

    A lateral grid pools its sub-grids (``_lateral_report``: neighbour J over all their
    pairs, the rule ``(beta, pm, gain_scale)`` of each attitude class counted in ``rules``);
    its coverage is the table's (``n_points`` and ``seed`` are the inner grids').
    """
    if grid.sub:
        return _lateral_report(grid)
    ja, jw = _neighbour_J(grid)
    return {
        "loop": grid.loop, "version": grid.version, "hash": grid.hash, "beta": grid.beta, "pm_deg": grid.pm_deg,
        "c1": grid.c1, "c3": grid.c3, "n_classes": grid.n, "n_levels": int(grid.level.max() + 1) if grid.level is not None else None,
        "neighbour_J_across_levels": _stats(ja),
        "neighbour_J_within_level": _stats(jw),
        "coverage": coverage(grid, n_points=n_points, seed=seed),
        "build_time_s": grid.built.get("build_time_s"),
        "built": grid.built,
    }
