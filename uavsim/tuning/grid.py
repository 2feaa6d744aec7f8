"""Class grids of the lumped parameter space, spaced by closed-loop performance.

A grid is the DNN's list of classes: each class is one lumped process with
its rule gains, its MRFT oscillation and the J matrix between classes
(``uavsim.tuning.jmatrix``). One versioned JSON file per loop family lives in
``uavsim/tuning/grids/`` and is read by data generation and training.

How a grid is built (``build_grid``). In the J convention of this project
(processes gain-normalized at their MRFT phase, rule controllers) a class's
controller depends only on its MRFT frequency ``Omega``, so J between two
processes is a function of ``Omega_i / Omega_j`` (and weakly of the true
process's shape): J = 1 exactly between processes of equal ``Omega``. The grid is
therefore spaced by J along ``Omega`` and spread over the rest of the box for
identification coverage:

1. Sample the box uniformly in log coordinates (seeded) and compute ``Omega``.
2. Calibrate the ratio ``r`` between neighbouring ``Omega`` levels so that the
   median symmetric ``J_(ij)`` of processes ``r`` apart is the target (1.10).
3. Cut ``[Omega_min, Omega_max]`` into geometric bands of ratio ``r``; a class
   level sits at each band's centre.
4. Share the class budget among levels in proportion to the box volume of
   their band (at least one each), and spread each level's classes over its
   iso-``Omega`` surface by k-means (log-box coordinates) on sample points in a
   thin slab around the level.

Lateral grids repeat this over ``(T2, tau_out)`` for each attitude class, with the
attitude loop closed by that class's rule PD, with three differences:

* each attitude class has its own MRFT ``beta`` (``choose_lateral_beta``: on a
  coarse sample, the candidate in [-0.9, -0.1] whose own-loop rule stabilizes
  the largest part of the box, then the smallest worst ISE deterioration
  against the ISE-optimal PD); the sub-grid's ``beta``/``c1``/``c3`` are its own;
* processes their own rule controller cannot stabilize (Nyquist test; a few are
  confirmed in time, ``verify_unstable``, counts in ``built``) have no finite
  own ISE, so J is undefined for them: they are excluded from the design and
  from coverage, and ``built["stable_fraction"]`` says how much of the box is left;
* the lateral MRFT frequency spans more than 15 J-spaced levels, so the levels
  are capped at the class target (neighbour J above 1.10).

    from uavsim.tuning.grid import load_grid
    g = load_grid("altitude"); g.n, g.kp[0], g.J.shape
    p = g.params_of(3)                   # LumpedParams with K = 1
    lat = load_grid("lateral").lateral(5)   # sub-grid of attitude class 5
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import tempfile
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.frequency import mrft_prediction_batch
from uavsim.lumped.params import RANGES, LumpedParams, loop_family
from uavsim.lumped.simulate import fourier_limit_cycle
from uavsim.tuning.jmatrix import deterioration, ise_normalized, j_matrix, symmetrize
from uavsim.tuning.rule import DEFAULT_BETA, DEFAULT_PM_DEG, TuningRule

__all__ = ["Grid", "load_grid", "save_grid", "build_grid", "grid_report", "GRID_VERSION", "TARGETS"]

GRID_VERSION = 1
#: class-count targets (paper) and neighbour J target
TARGETS = {"attitude": 48, "altitude": 208, "lateral": 15, "J": 1.10}
_AXES = {"attitude": ("T_prop", "T1", "tau"), "altitude": ("T_prop", "T1", "tau"), "lateral": ("T2", "tau")}


def _grid_dir() -> Path:
    return Path(str(resources.files("uavsim.tuning"))) / "grids"


@dataclass
class Grid:
    """Classes of one loop family (see module docstring).

    Arrays have shape (n,) (``J``: (n, n), rows predicted, columns true). Gains are
    for a unit-gain process (K = 1); ``omega``/``amplitude``/``period`` are the exact
    MRFT oscillation at ``beta`` with h = 1, K = 1; ``omega_df`` the DF frequency
    the rule uses. ``level`` is each class's ``Omega`` level index.
    """

    loop: str
    version: int
    params: dict[str, np.ndarray]
    kp: np.ndarray
    kd: np.ndarray
    derivative_filter_hz: np.ndarray
    omega: np.ndarray
    amplitude: np.ndarray
    omega_df: np.ndarray
    J: np.ndarray
    beta: float
    pm_deg: float
    c1: float
    c3: float
    built: dict[str, Any]
    level: np.ndarray | None = None
    attitude: dict[str, float] | None = None  # lateral sub-grids: the attitude class
    sub: list[Grid] = field(default_factory=list)  # lateral: one per attitude class
    hash: str = ""

    @property
    def n(self) -> int:
        return len(self.kp)

    @property
    def period(self) -> np.ndarray:
        return 2 * np.pi / self.omega

    def lateral(self, att_class: int) -> Grid:
        """Sub-grid of attitude class ``att_class`` (lateral grids only)."""
        if not self.sub:
            raise UserError(f"{self.loop} grid has no lateral sub-grids")
        if not 0 <= att_class < len(self.sub):
            raise UserError(f"attitude class {att_class} out of range 0..{len(self.sub) - 1}")
        return self.sub[att_class]

    def params_of(self, i: int) -> LumpedParams:
        """Class ``i`` as ``LumpedParams`` with K = 1."""
        if self.sub:
            raise UserError("a lateral grid has one sub-grid per attitude class: use grid.lateral(a).params_of(i)")
        if not 0 <= i < self.n:
            raise UserError(f"class {i} out of range 0..{self.n - 1}")
        if self.attitude is not None:
            a = self.attitude
            return LumpedParams(
                "lateral_x", 1.0, a["T_prop"], a["T1"], float(self.params["tau"][i]), T2=float(self.params["T2"][i]),
                tau_in=a["tau_in"], att_kp=a["att_kp"], att_kd=a["att_kd"], att_filter_hz=a["att_filter_hz"],
            )
        loop = "attitude" if self.loop == "attitude" else "altitude"
        loop = "roll" if loop == "attitude" else loop
        return LumpedParams(loop, 1.0, float(self.params["T_prop"][i]), float(self.params["T1"][i]), float(self.params["tau"][i]))

    # --- serialization -------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        def arr(x, nd=8):
            return [float(f"{v:.{nd}g}") for v in np.asarray(x).ravel()]

        d: dict[str, Any] = {"loop": self.loop, "version": self.version, "beta": self.beta, "pm_deg": self.pm_deg,
                             "c1": self.c1, "c3": self.c3, "built": self.built}
        if self.sub:
            d["sub"] = [s.to_dict() for s in self.sub]
            return d
        d.update({
            "params": {k: arr(v) for k, v in self.params.items()},
            "kp": arr(self.kp), "kd": arr(self.kd), "derivative_filter_hz": arr(self.derivative_filter_hz),
            "omega": arr(self.omega), "amplitude": arr(self.amplitude), "omega_df": arr(self.omega_df),
            "J": [arr(row, 5) for row in self.J],
        })
        if self.level is not None:
            d["level"] = [int(v) for v in self.level]
        if self.attitude is not None:
            d["attitude"] = self.attitude
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Grid:
        common = {k: d[k] for k in ("loop", "version", "beta", "pm_deg", "c1", "c3", "built")}
        if "sub" in d:
            g = cls(params={}, kp=np.zeros(0), kd=np.zeros(0), derivative_filter_hz=np.zeros(0), omega=np.zeros(0),
                    amplitude=np.zeros(0), omega_df=np.zeros(0), J=np.zeros((0, 0)), **common)
            g.sub = [cls.from_dict(s) for s in d["sub"]]
            return g
        a = {k: np.asarray(d[k], float) for k in ("kp", "kd", "derivative_filter_hz", "omega", "amplitude", "omega_df")}
        return cls(params={k: np.asarray(v, float) for k, v in d["params"].items()}, J=np.asarray(d["J"], float),
                   level=np.asarray(d["level"], int) if "level" in d else None, attitude=d.get("attitude"), **a, **common)


def _content_hash(d: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()


def save_grid(grid: Grid, path: str | os.PathLike | None = None) -> Path:
    """Write the grid as JSON atomically (temp file, then ``os.replace``); return the path."""
    path = Path(path) if path is not None else _grid_dir() / f"{grid.loop}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    d = grid.to_dict()
    d["hash"] = _content_hash(d)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(d, f, separators=(",", ":"))
    os.chmod(tmp, 0o644)  # mkstemp makes 0600; the artefact is package data
    os.replace(tmp, path)
    grid.hash = d["hash"]
    return path


def load_grid(loop: str, path: str | os.PathLike | None = None) -> Grid:
    """Load the grid of a loop (``attitude``/``roll``/``pitch``, ``altitude``, ``lateral``/``lateral_x``/``lateral_y``)."""
    fam = loop_family(loop)
    path = Path(path) if path is not None else _grid_dir() / f"{fam}.json"
    if not path.exists():
        raise UserError(f"no {fam} grid at {path} (run `uavsim grid build --loop {fam}`)")
    try:
        d = json.loads(path.read_text())
        h = d.pop("hash", "")
        if h and h != _content_hash(d):
            raise UserError(f"grid file {path} is corrupt (hash mismatch)")
        if d.get("version") != GRID_VERSION:
            raise UserError(f"grid file {path} has version {d.get('version')}, expected {GRID_VERSION}")
        g = Grid.from_dict(d)
    except (KeyError, ValueError, TypeError) as exc:
        raise UserError(f"grid file {path} is malformed: {exc}") from exc
    g.hash = h
    return g


# --- building ---------------------------------------------------------------------------

def _log_box(fam: str) -> tuple[np.ndarray, np.ndarray]:
    box = RANGES[fam]
    lo = np.log([box[k][0] for k in _AXES[fam]])
    hi = np.log([box[k][1] for k in _AXES[fam]])
    return lo, hi


def _omega(fam: str, X: np.ndarray, beta: float, att: dict | None) -> np.ndarray:
    """DF MRFT frequency of points X (P, d) in the family's axes."""
    if fam == "lateral":
        w, _ = mrft_prediction_batch("lateral", beta, 1.0, K=1.0, T_prop=att["T_prop"], T1=att["T1"], tau=X[:, 1],
                                     T2=X[:, 0], tau_in=att["tau_in"], att_kp=att["att_kp"], att_kd=att["att_kd"],
                                     att_N=2 * np.pi * att["att_filter_hz"])
        return w
    return mrft_prediction_batch(fam, beta, 1.0, K=1.0, T_prop=X[:, 0], T1=X[:, 1], tau=X[:, 2])[0]


def _proc_params(fam: str, X: np.ndarray, att: dict | None) -> dict[str, Any]:
    if fam == "lateral":
        return {"T_prop": att["T_prop"], "T1": att["T1"], "tau": X[:, 1], "T2": X[:, 0], "tau_in": att["tau_in"],
                "att_kp": att["att_kp"], "att_kd": att["att_kd"], "att_N": 2 * np.pi * att["att_filter_hz"]}
    return {"T_prop": X[:, 0], "T1": X[:, 1], "tau": X[:, 2]}


def _calibrate_ratio(fam: str, X: np.ndarray, w: np.ndarray, c1: float, c3: float, target: float, att) -> float:
    """Omega ratio r whose median symmetric J (processes r apart) equals ``target``."""
    rs = np.exp(np.linspace(0.01, 0.6, 25))
    ctrl = np.concatenate([w[:, None] * rs[None, :], w[:, None] / rs[None, :]], axis=1)  # (P, 2R)
    Js = np.empty((len(w), len(rs)))
    for j in range(len(w)):
        Q, own = ise_normalized(fam, w[j:j + 1], ctrl[j], c1, c3, include_own=True, **_proc_params(fam, X[j:j + 1], att))
        Jj = np.clip(Q[:, 0] / own[0], 1.0, 1e3)
        Js[j] = np.maximum(Jj[: len(rs)], Jj[len(rs):])
    med = np.median(Js, axis=0)
    return float(np.exp(np.interp(math.log(target), np.log(med), np.log(rs))))


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


def own_loop_stable(fam: str, X: np.ndarray, w: np.ndarray, rule: TuningRule, att: dict | None) -> np.ndarray:
    """Whether each process X (P, d) is stable under its own rule controller, (P,) bool.

    Nyquist test of ``uavsim.lumped.ise`` on the rule PD (filter ``10 Omega``)
    and the process (``w``: its DF MRFT frequencies, rad/s, all finite).
    """
    from uavsim.lumped.ise import step_ise_batch

    pp = _proc_params(fam, X, att)
    g = rule.gains_batch(fam, K=1.0, **pp)
    _, stable = step_ise_batch(fam, g["kp"], g["kd"], g["N"], w, n=1500, return_stable=True, K=1.0, **pp)
    return stable


def _design(fam: str, n_target: int, rule: TuningRule, rng: np.random.Generator, n_samples: int,
            target_J: float, att: dict | None = None, n_calib: int = 40, stable_only: bool = False,
            max_levels: int | None = None) -> dict[str, Any]:
    c1, c3 = rule.constants
    lo, hi = _log_box(fam)
    U = rng.random((n_samples, len(lo)))
    X = np.exp(lo + (hi - lo) * U)
    w = _omega(fam, X, rule.beta, att)
    ok = np.isfinite(w)
    U, X, w = U[ok], X[ok], w[ok]
    n_sampled = len(w)
    if stable_only:
        # a process its own rule controller cannot stabilize has no finite ISE:
        # J (a ratio to that ISE) is undefined for it, so it cannot be a class
        ok = own_loop_stable(fam, X, w, rule, att)
        U, X, w = U[ok], X[ok], w[ok]
        if len(w) < 3:
            raise UserError(f"{fam}: fewer than 3 sampled processes are stable under their own rule at beta={rule.beta}")
    r = _calibrate_ratio(fam, X[:n_calib], w[:n_calib], c1, c3, target_J, att)
    lw = np.log(w)
    lmin, lmax = lw.min(), lw.max()
    n_lev = max(1, int(math.ceil((lmax - lmin) / math.log(r) - 1e-9)))
    if max_levels is not None:
        # a class budget smaller than the J-spaced level count: wider levels, larger neighbour J
        n_lev = min(n_lev, max_levels)
    step = (lmax - lmin) / n_lev  # <= log r: levels exactly tile the range
    band = np.minimum(((lw - lmin) / step).astype(int), n_lev - 1)
    vol = np.bincount(band, minlength=n_lev).astype(float)
    # budget: at least one class per level, the rest in proportion to band volume
    extra = max(n_target - n_lev, 0)
    share = vol / vol.sum() * extra
    alloc = 1 + np.floor(share).astype(int)
    rem = extra - (alloc - 1).sum()
    alloc[np.argsort(-(share - np.floor(share)))[:rem]] += 1
    chosen, levels = [], []
    for lev in range(n_lev):
        centre = lmin + (lev + 0.5) * step
        slab = np.nonzero(np.abs(lw - centre) < 0.1 * step)[0]
        if len(slab) < 3 * alloc[lev]:
            slab = np.nonzero(band == lev)[0]
        idx = slab[_kmeans(U[slab], int(alloc[lev]), rng)]
        chosen.extend(idx.tolist())
        levels.extend([lev] * len(idx))
    chosen = np.array(chosen)
    return {"X": X[chosen], "level": np.array(levels), "ratio": r, "n_levels": n_lev, "level_step": math.exp(step),
            "omega_range": [float(w.min()), float(w.max())], "stable_fraction": len(w) / max(n_sampled, 1)}


def _finish(fam: str, loop_name: str, design: dict, rule: TuningRule, att: dict | None, built: dict,
            cycle_kw: dict | None = None) -> Grid:
    X = design["X"]
    c1, c3 = rule.constants
    pp = _proc_params(fam, X, att)
    g = rule.gains_batch(fam, K=1.0, **pp)
    J = j_matrix(fam, g["omega"], c1, c3, **pp)
    w_ex, a_ex = np.empty(len(X)), np.empty(len(X))
    for i in range(len(X)):
        p = _as_params(fam, X[i], att)
        T, a = fourier_limit_cycle(p, rule.beta, 1.0, **(cycle_kw or {}))
        w_ex[i], a_ex[i] = 2 * np.pi / T, a
    params = {k: X[:, i] for i, k in enumerate(_AXES[fam])}
    return Grid(loop=loop_name, version=GRID_VERSION, params=params, kp=g["kp"], kd=g["kd"],
                derivative_filter_hz=g["derivative_filter_hz"], omega=w_ex, amplitude=a_ex, omega_df=g["omega"], J=J,
                beta=rule.beta, pm_deg=rule.pm_deg, c1=c1, c3=c3, built=built, level=design["level"], attitude=att)


def _as_params(fam: str, x: np.ndarray, att: dict | None) -> LumpedParams:
    if fam == "lateral":
        return LumpedParams("lateral_x", 1.0, att["T_prop"], att["T1"], float(x[1]), T2=float(x[0]), tau_in=att["tau_in"],
                            att_kp=att["att_kp"], att_kd=att["att_kd"], att_filter_hz=att["att_filter_hz"])
    return LumpedParams("roll" if fam == "attitude" else "altitude", 1.0, float(x[0]), float(x[1]), float(x[2]))


def build_grid(loop: str, beta: float = DEFAULT_BETA, pm_deg: float = DEFAULT_PM_DEG, seed: int = 0,
               n_target: int | None = None, target_J: float = TARGETS["J"], log=None) -> Grid:
    """Build the grid of a loop family (see module docstring). Returns an unsaved ``Grid``."""
    from uavsim import __version__ as tool_version

    fam = loop_family(loop)
    rule = TuningRule(beta, pm_deg)
    _ = rule.constants  # validates
    rng = np.random.default_rng(seed)
    t0 = time.time()
    built: dict[str, Any] = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), "tool_version": tool_version,
                             "seed": seed, "target_J": target_J, "method": "omega levels spaced by J + k-means on iso-Omega slabs"}
    if fam != "lateral":
        n_target = n_target or TARGETS[fam]
        d = _design(fam, n_target, rule, rng, 40000, target_J)
        built.update(n_target=n_target, level_ratio=d["ratio"], n_levels=d["n_levels"], level_step=d["level_step"],
                     omega_range=d["omega_range"])
        g = _finish(fam, fam, d, rule, None, built)
        built["build_time_s"] = round(time.time() - t0, 1)
        return g
    return _build_lateral(rule, rng, t0, built, n_target or TARGETS["lateral"], target_J, log)


#: candidate MRFT betas of the lateral loops (the authors' search bounds, step 0.1)
LATERAL_BETAS = tuple(round(b, 2) for b in np.arange(-0.9, -0.05, 0.1))


def attitude_of(att_grid: Grid, a: int) -> dict[str, float]:
    """The attitude class ``a`` as the dict a lateral sub-grid stores (unit-gain rule PD)."""
    return {"T_prop": float(att_grid.params["T_prop"][a]), "T1": float(att_grid.params["T1"][a]),
            "tau_in": float(att_grid.params["tau"][a]), "att_kp": float(att_grid.kp[a]), "att_kd": float(att_grid.kd[a]),
            "att_filter_hz": float(att_grid.derivative_filter_hz[a]), "att_class": a}


def choose_lateral_beta(att: dict, pm_deg: float, rng: np.random.Generator, n_points: int = 10,
                        betas: tuple[float, ...] = LATERAL_BETAS, tol: float = 0.05) -> dict[str, Any]:
    """MRFT beta of the lateral loop over one attitude class.

    On a coarse log-uniform sample of the (T2, tau_out) box plus its four
    corners, each candidate beta's rule (at ``pm_deg``) is scored by the
    fraction of points its own-loop controller stabilizes and by its worst ISE
    deterioration ``Q(rule) / Q(ISE-optimal PD)`` over the points it
    stabilizes. The beta with the largest stable fraction (within ``tol``) and,
    among those, the smallest worst deterioration is chosen: over slow attitude
    classes no beta stabilizes the whole box (the lateral cycle sits on the
    attitude loop's resonance), so the stable fraction comes first.

    Returns
    -------
    dict: ``beta``, ``stable_fraction``, ``worst_deterioration``, ``table``
    (rows ``[beta, stable_fraction, worst_deterioration]``), ``n_points``.
    """
    from uavsim.lumped.ise import step_ise_batch
    from uavsim.tuning.search import optimal_pd

    lo, hi = _log_box("lateral")
    X = np.vstack([np.exp(lo + (hi - lo) * rng.random((n_points, 2))),
                   np.exp(np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]]))])
    pp = _proc_params("lateral", X, att)
    # the optimal PD starts from a safe point: half the beta = -0.1 rule, the most stable one
    safe = TuningRule(-0.1, pm_deg).gains_batch("lateral", K=1.0, **pp)
    q_opt = np.empty(len(X))
    for i in range(len(X)):
        pi = {k: (np.asarray(v).reshape(-1)[i] if np.size(v) > 1 else v) for k, v in pp.items()}
        _, _, q_opt[i] = optimal_pd("lateral", {"K": 1.0, **pi}, float(safe["N"][i]), float(safe["omega"][i]),
                                    (0.5 * float(safe["kp"][i]), 0.5 * float(safe["kd"][i])))
    table = []
    for b in betas:
        rule = TuningRule(b, pm_deg)
        try:
            g = rule.gains_batch("lateral", K=1.0, **pp)
        except UserError:
            table.append([float(b), 0.0, math.inf])
            continue
        q = step_ise_batch("lateral", g["kp"], g["kd"], g["N"], g["omega"], n=1500, K=1.0, **pp)
        fin = np.isfinite(q) & np.isfinite(q_opt)
        worst = float(np.max(q[fin] / q_opt[fin])) if fin.any() else math.inf
        table.append([float(b), float(np.mean(np.isfinite(q))), worst])
    best_frac = max(r[1] for r in table)
    cands = [r for r in table if r[1] >= best_frac - tol]
    b, frac, worst = min(cands, key=lambda r: r[2])
    # JSON has no infinity: an unusable beta's worst deterioration is stored as null
    table = [[r[0], r[1], r[2] if math.isfinite(r[2]) else None] for r in table]
    return {"beta": b, "stable_fraction": frac, "worst_deterioration": worst if math.isfinite(worst) else None,
            "table": table, "n_points": len(X)}


def verify_unstable(points: list[tuple[dict, float, np.ndarray]], pm_deg: float, periods: float = 30.0) -> np.ndarray:
    """Time-domain check of Nyquist instability claims, (m,) bool: True where the step diverges.

    ``points``: (attitude dict, beta, x = (T2, tau_out)). Each process is
    simulated (``uavsim.lumped.simulate``, 1 ms, sampled PD) under its own rule
    controller for ``periods`` MRFT periods; it counts as diverging when the
    error's envelope over the last third exceeds 10 times the unit step.
    """
    from uavsim.lumped.simulate import simulate_pd_step_batch

    if not points:
        return np.zeros(0, bool)
    cols: dict[str, list] = {}
    gains: dict[str, list] = {"kp": [], "kd": [], "N": [], "omega": []}
    for att, beta, x in points:
        pp = _proc_params("lateral", np.asarray(x, float)[None, :], att)
        g = TuningRule(beta, pm_deg).gains_batch("lateral", K=1.0, **pp)
        for k, v in pp.items():
            cols.setdefault(k, []).append(float(np.asarray(v).reshape(-1)[0]))
        for k in gains:
            gains[k].append(float(g[k][0]))
    dt = 1e-3
    steps = int(periods * 2 * np.pi / min(gains["omega"]) / dt)
    res = simulate_pd_step_batch("lateral", np.array(gains["kp"]), np.array(gains["kd"]), np.array(gains["N"]), dt,
                                 steps, K=1.0, **{k: np.array(v) for k, v in cols.items()})
    e = res["e"]
    tail = np.abs(e[:, -steps // 3:])
    return ~np.isfinite(tail).all(axis=1) | (np.nan_to_num(tail, nan=np.inf).max(axis=1) > 10.0)


def _build_lateral(rule: TuningRule, rng: np.random.Generator, t0: float, built: dict[str, Any], n_target: int,
                   target_J: float, log) -> Grid:
    """One sub-grid per attitude class, each at its own beta, over its stable part of the box."""
    att_grid = load_grid("attitude")
    built.update(n_target=n_target, attitude_hash=att_grid.hash,
                 method="per attitude class: beta by stable fraction then worst ISE deterioration; omega levels "
                        "spaced by J + k-means on iso-Omega slabs over the points stable under their own rule")
    subs, checks = [], []
    for a in range(att_grid.n):
        att = attitude_of(att_grid, a)
        choice = choose_lateral_beta(att, rule.pm_deg, rng)
        sub_rule = TuningRule(choice["beta"], rule.pm_deg)
        d = _design("lateral", n_target, sub_rule, rng, 800, target_J, att=att, n_calib=8, stable_only=True,
                    max_levels=n_target)
        sb = {"level_ratio": d["ratio"], "n_levels": d["n_levels"], "level_step": d["level_step"],
              "omega_range": d["omega_range"], "stable_fraction": d["stable_fraction"], "beta_choice": choice}
        # the lateral response rolls off at least as 1/w^3: 150 odd harmonics are plenty
        subs.append(_finish("lateral", "lateral", d, sub_rule, att, sb, cycle_kw={"n_harm": 150, "n_t": 1000}))
        # two unstable sample points per class for the time-domain check
        lo, hi = _log_box("lateral")
        Xs = np.exp(lo + (hi - lo) * rng.random((200, 2)))
        ws = _omega("lateral", Xs, sub_rule.beta, att)
        fin = np.isfinite(ws)
        bad = np.flatnonzero(~own_loop_stable("lateral", Xs[fin], ws[fin], sub_rule, att))[:2]
        checks += [(att, sub_rule.beta, Xs[fin][j]) for j in bad]
        if log:
            log(f"lateral sub-grid {a + 1}/{att_grid.n}: beta {sub_rule.beta}, {subs[-1].n} classes, "
                f"{100 * d['stable_fraction']:.0f}% of the box stable ({time.time() - t0:.0f} s)")
    diverged = verify_unstable(checks, rule.pm_deg)
    built["instability_check"] = {"n_points": len(checks), "n_diverged_in_time": int(diverged.sum())}
    built["lateral_betas"] = [s.beta for s in subs]
    g = Grid(loop="lateral", version=GRID_VERSION, params={}, kp=np.zeros(0), kd=np.zeros(0),
             derivative_filter_hz=np.zeros(0), omega=np.zeros(0), amplitude=np.zeros(0), omega_df=np.zeros(0),
             J=np.zeros((0, 0)), beta=rule.beta, pm_deg=rule.pm_deg, c1=rule.constants[0], c3=rule.constants[1],
             built=built, sub=subs)
    built["build_time_s"] = round(time.time() - t0, 1)
    return g


# --- report ---------------------------------------------------------------------------

def neighbour_pairs(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour pairs: for each class, its nearest class (log-box distance) in each adjacent
    Omega level (``across``) and in its own level (``within``); arrays of (i, j) rows."""
    fam = loop_family(grid.loop)
    lo, hi = _log_box(fam)
    Z = (np.log(np.column_stack([grid.params[k] for k in _AXES[fam]])) - lo) / (hi - lo)
    across, within = [], []
    for i in range(grid.n):
        d = ((Z - Z[i]) ** 2).sum(1)
        for dl, out in ((-1, across), (1, across), (0, within)):
            m = np.nonzero((grid.level == grid.level[i] + dl) & (np.arange(grid.n) != i))[0]
            if len(m):
                out.append((i, m[np.argmin(d[m])]))
    return np.array(across, int).reshape(-1, 2), np.array(within, int).reshape(-1, 2)


def _stats(x: np.ndarray) -> dict[str, float]:
    if len(x) == 0:
        return {"mean": float("nan"), "min": float("nan"), "max": float("nan"), "n": 0}
    return {"mean": float(np.mean(x)), "min": float(np.min(x)), "max": float(np.max(x)), "n": int(len(x))}


def coverage(grid: Grid, n_points: int = 2000, seed: int = 1) -> dict[str, Any]:
    """Worst-case J between random box points and the class each would be assigned.

    The assignment is the best available class for the point (what an ideal
    J-trained classifier returns): ``min_i J(C_i, G_x)``. Also reported: the
    assignment to the class at the point's own Omega level nearest in log-box space.
    """
    fam = loop_family(grid.loop)
    rng = np.random.default_rng(seed)
    lo, hi = _log_box(fam)
    X = np.exp(lo + (hi - lo) * rng.random((n_points, len(lo))))
    att = grid.attitude
    w = _omega(fam, X, grid.beta, att)
    ok = np.isfinite(w)
    X, w = X[ok], w[ok]
    extra: dict[str, Any] = {}
    if fam == "lateral":
        # J is a ratio to the point's own-rule ISE: undefined where that loop is unstable
        st = own_loop_stable(fam, X, w, TuningRule(grid.beta, grid.pm_deg), att)
        extra = {"stable_fraction": float(st.mean())}
        X, w = X[st], w[st]
    if len(w) == 0:
        return {"n_points": 0, "worst_J": float("nan"), "p99_J": float("nan"), "mean_J": float("nan"), **extra}
    D = deterioration(fam, w, grid.omega_df, grid.c1, grid.c3, **_proc_params(fam, X, att))  # (n, P)
    best = D.min(axis=0)
    return {"n_points": int(len(w)), "worst_J": float(best.max()), "p99_J": float(np.quantile(best, 0.99)),
            "mean_J": float(best.mean()), **extra}


def grid_report(grid: Grid, n_points: int = 2000, seed: int = 1) -> dict[str, Any]:
    """Counts, neighbour-J statistics, coverage and build figures of a grid."""
    if grid.sub:
        per = [grid_report(s, n_points=max(n_points // len(grid.sub), 10), seed=seed + k) for k, s in enumerate(grid.sub)]
        return {
            "loop": grid.loop, "version": grid.version, "hash": grid.hash, "beta": grid.beta, "pm_deg": grid.pm_deg,
            "n_subgrids": len(grid.sub), "n_classes_total": int(sum(s.n for s in grid.sub)),
            "n_classes_min": int(min(s.n for s in grid.sub)), "n_classes_max": int(max(s.n for s in grid.sub)),
            "neighbour_J_across_levels": {"mean": float(np.nanmean([p["neighbour_J_across_levels"]["mean"] for p in per])),
                                          "min": float(np.nanmin([p["neighbour_J_across_levels"]["min"] for p in per])),
                                          "max": float(np.nanmax([p["neighbour_J_across_levels"]["max"] for p in per]))},
            "neighbour_J_across_levels_median": float(np.nanmedian([p["neighbour_J_across_levels"]["mean"] for p in per])),
            "coverage": {"n_points": int(sum(p["coverage"]["n_points"] for p in per)),
                         "worst_J": float(np.nanmax([p["coverage"]["worst_J"] for p in per])),
                         "p99_J_median": float(np.nanmedian([p["coverage"]["p99_J"] for p in per])),
                         "mean_J": float(np.nanmean([p["coverage"]["mean_J"] for p in per])),
                         "stable_fraction": float(np.mean([p["coverage"].get("stable_fraction", 1.0) for p in per]))},
            "betas": [s.beta for s in grid.sub],
            "build_time_s": grid.built.get("build_time_s"), "built": grid.built,
        }
    Js = symmetrize(grid.J)
    across, within = neighbour_pairs(grid)
    return {
        "loop": grid.loop, "version": grid.version, "hash": grid.hash, "beta": grid.beta, "pm_deg": grid.pm_deg,
        "c1": grid.c1, "c3": grid.c3, "n_classes": grid.n, "n_levels": int(grid.level.max() + 1) if grid.level is not None else None,
        "neighbour_J_across_levels": _stats(Js[across[:, 0], across[:, 1]] if len(across) else np.zeros(0)),
        "neighbour_J_within_level": _stats(Js[within[:, 0], within[:, 1]] if len(within) else np.zeros(0)),
        "coverage": coverage(grid, n_points=n_points, seed=seed),
        "build_time_s": grid.built.get("build_time_s"),
        "built": grid.built,
    }
