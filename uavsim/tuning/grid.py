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

Lateral grids (``uavsim.tuning.lateral_grid``) have one sub-grid of the
``(T2, tau_out)`` box per attitude class, designed on the loop actually flown: the
attitude loop closed by the attitude class's table PD sampled at the control rate.
Their classes are a cover of a box sample by the table's J (the lateral optima are
too fragile for ``Omega`` levels), with explicit neighbour pairs (``Grid.neighbours``)
instead of levels, and each has its own relay ``beta`` (the lowest NP-MRFT allows on
its fastest cycle) and rule.

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
from uavsim.tuning.jmatrix import J_MAX, ise_normalized, j_matrix, symmetrize
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
    #: the rule's loop gain at Omega (``uavsim.tuning.rule``): 1 for the inner loops
    gain_scale: float = 1.0
    attitude: dict[str, float] | None = None  # lateral sub-grids: the attitude class
    #: lateral sub-grids: neighbouring class pairs ``[i, k]`` (``neighbour_pairs``), in place of levels
    neighbours: list[list[int]] | None = None
    sub: list[Grid] = field(default_factory=list)  # lateral: one per attitude class
    hash: str = ""

    @property
    def n(self) -> int:
        return len(self.kp)

    @property
    def period(self) -> np.ndarray:
        return 2 * np.pi / self.omega

    @property
    def rule(self) -> TuningRule:
        """The tuning rule of the classes' gains."""
        return TuningRule(self.beta, self.pm_deg, self.gain_scale)

    def lateral(self, att_class: int) -> Grid:
        """Sub-grid of attitude class ``att_class`` (lateral grids only)."""
        return sub_of(self.sub, att_class, f"{self.loop} grid")

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
        if self.gain_scale != 1.0:  # only the lateral rules have one: the inner grids' files (and hashes) stay as they are
            d["gain_scale"] = self.gain_scale
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
        if self.neighbours is not None:
            d["neighbours"] = [[int(i), int(k)] for i, k in self.neighbours]
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
                   level=np.asarray(d["level"], int) if "level" in d else None, attitude=d.get("attitude"),
                   neighbours=d.get("neighbours"), gain_scale=float(d.get("gain_scale", 1.0)), **a, **common)


def _content_hash(d: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()


def write_hashed_json(d: dict[str, Any], path: Path) -> str:
    """Write ``d`` with its content hash as JSON atomically (temp file, then ``os.replace``); return the hash."""
    path.parent.mkdir(parents=True, exist_ok=True)
    d = {**d, "hash": _content_hash(d)}
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(d, f, separators=(",", ":"))
    os.chmod(tmp, 0o644)  # mkstemp makes 0600; the artefact is package data
    os.replace(tmp, path)
    return d["hash"]


def read_hashed_json(path: Path, what: str, problem, parse) -> tuple[Any, str]:
    """Read a file of ``write_hashed_json``: ``(parse(content), hash)``.

    ``problem(content)`` returns what is wrong with a well-formed file (e.g. its version) or None;
    a corrupt, malformed or wrong file is a one-line UserError naming it.
    """
    try:
        d = json.loads(path.read_text())
        h = d.pop("hash", "")
        if h and h != _content_hash(d):
            raise UserError(f"{what} file {path} is corrupt (hash mismatch)")
        msg = problem(d)
        if msg:
            raise UserError(f"{what} file {path} {msg}")
        return parse(d), h
    except (KeyError, ValueError, TypeError, AttributeError) as exc:
        raise UserError(f"{what} file {path} is malformed: {exc}") from exc


def sub_of(subs: list, att_class: int, owner: str):
    """``subs[att_class]`` of a lateral grid or table (``owner`` names it in the errors)."""
    if not subs:
        raise UserError(f"{owner} has no lateral sub-{'grids' if 'grid' in owner else 'tables'}")
    if not 0 <= att_class < len(subs):
        raise UserError(f"attitude class {att_class} out of range 0..{len(subs) - 1}")
    return subs[att_class]


def save_grid(grid: Grid, path: str | os.PathLike | None = None) -> Path:
    """Write the grid as JSON atomically (temp file, then ``os.replace``); return the path."""
    path = Path(path) if path is not None else _grid_dir() / f"{grid.loop}.json"
    grid.hash = write_hashed_json(grid.to_dict(), path)
    return path


def load_grid(loop: str, path: str | os.PathLike | None = None) -> Grid:
    """Load the grid of a loop (``attitude``/``roll``/``pitch``, ``altitude``, ``lateral``/``lateral_x``/``lateral_y``)."""
    fam = loop_family(loop)
    path = Path(path) if path is not None else _grid_dir() / f"{fam}.json"
    if not path.exists():
        raise UserError(f"no {fam} grid at {path} (run `uavsim grid build --loop {fam}`)")
    g, h = read_hashed_json(path, "grid", lambda d: None if d.get("version") == GRID_VERSION else
                            f"has version {d.get('version')}, expected {GRID_VERSION}", Grid.from_dict)
    g.hash = h
    return g


# --- building ---------------------------------------------------------------------------

def _log_box(fam: str) -> tuple[np.ndarray, np.ndarray]:
    box = RANGES[fam]
    lo = np.log([box[k][0] for k in _AXES[fam]])
    hi = np.log([box[k][1] for k in _AXES[fam]])
    return lo, hi


def _omega(fam: str, X: np.ndarray, beta: float, att: dict | None) -> np.ndarray:
    """DF MRFT frequency of points X (P, d) in the family's axes (lateral: over the attitude dict ``att``)."""
    return mrft_prediction_batch(fam, beta, 1.0, K=1.0, **_proc_params(fam, X, att))[0]


def _proc_params(fam: str, X: np.ndarray, att: dict | None) -> dict[str, Any]:
    if fam == "lateral":
        # a lateral grid's attitude PD runs at the control rate (``rate_hz``); older grids' ran continuous
        return {"T_prop": att["T_prop"], "T1": att["T1"], "tau": X[:, 1], "T2": X[:, 0], "tau_in": att["tau_in"],
                "att_kp": att["att_kp"], "att_kd": att["att_kd"], "att_N": 2 * np.pi * att["att_filter_hz"],
                "att_rate_hz": att.get("rate_hz")}
    return {"T_prop": X[:, 0], "T1": X[:, 1], "tau": X[:, 2]}


#: Omega ratios at which the J curves of the level calibration are sampled
_RATIOS = np.exp(np.linspace(0.01, 0.6, 25))


def _j_curves(fam: str, X: np.ndarray, w: np.ndarray, c1: float, c3: float, att) -> np.ndarray:
    """Symmetric J of each process X (P, d) against rule controllers ``r`` apart in Omega, (P, R).

    Entry ``[j, k]`` is ``max(J(C(w_j r_k), G_j), J(C(w_j / r_k), G_j))`` for ``r_k`` in ``_RATIOS``.
    """
    ctrl = np.concatenate([w[:, None] * _RATIOS[None, :], w[:, None] / _RATIOS[None, :]], axis=1)  # (P, 2R)
    Js = np.empty((len(w), len(_RATIOS)))
    for j in range(len(w)):
        Q, own = ise_normalized(fam, w[j:j + 1], ctrl[j], c1, c3, include_own=True, **_proc_params(fam, X[j:j + 1], att))
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
    lo, hi = _log_box(fam)
    U = rng.random((n_samples, len(lo)))
    X = np.exp(lo + (hi - lo) * U)
    w = _omega(fam, X, rule.beta, None)
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
    pp = _proc_params(fam, X, None)
    g = rule.gains_batch(fam, K=1.0, **pp)
    J = j_matrix(fam, g["omega"], c1, c3, **pp)
    w_ex, a_ex = np.empty(len(X)), np.empty(len(X))
    for i in range(len(X)):
        p = LumpedParams("roll" if fam == "attitude" else "altitude", 1.0, float(X[i, 0]), float(X[i, 1]), float(X[i, 2]))
        T, a = fourier_limit_cycle(p, rule.beta, 1.0)
        w_ex[i], a_ex[i] = 2 * np.pi / T, a
    params = {k: X[:, i] for i, k in enumerate(_AXES[fam])}
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


def attitude_of(att_grid: Grid, a: int, att_table=None) -> dict[str, float]:
    """The attitude class ``a`` as the dict a lateral sub-grid stores: ``T_prop``, ``T1``, ``tau_in``
    (s), the unit-gain attitude PD ``att_kp``, ``att_kd``, ``att_filter_hz`` and ``att_class``.

    With ``att_table`` (``uavsim.tuning.table.OptimalTable`` of the attitude grid) the PD is the
    table's ISE-optimal one, flown at the table's rate, which the dict adds as ``rate_hz``; without,
    the grid's rule PD (continuous).
    """
    src = att_grid if att_table is None else att_table
    d = {"T_prop": float(att_grid.params["T_prop"][a]), "T1": float(att_grid.params["T1"][a]),
         "tau_in": float(att_grid.params["tau"][a]), "att_kp": float(src.kp[a]), "att_kd": float(src.kd[a]),
         "att_filter_hz": float(src.derivative_filter_hz[a]), "att_class": int(a)}
    if att_table is not None:
        d["rate_hz"] = float(att_table.rate_hz)
    return d


def _box_sample(fam: str, rng: np.random.Generator, n: int, corners: bool = False) -> np.ndarray:
    """``n`` log-uniform points of the family's box, (n, d), then its corners if asked (2-d boxes)."""
    lo, hi = _log_box(fam)
    X = np.exp(lo + (hi - lo) * rng.random((n, len(lo))))
    if corners:
        X = np.vstack([X, np.exp(np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]]))])
    return X


def neighbour_pairs(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour pairs: for each class, its nearest class (log-box distance) in each adjacent
    Omega level (``across``) and in its own level (``within``); arrays of (i, j) rows.

    A grid with explicit ``neighbours`` (the lateral sub-grids: a cover, not levels) returns them
    as ``across`` (each pair once, ``i < j``) and no ``within`` pairs.
    """
    if grid.neighbours is not None:
        return np.asarray(grid.neighbours, dtype=int).reshape(-1, 2), np.zeros((0, 2), dtype=int)
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
    X = _box_sample(fam, np.random.default_rng(seed), n_points)
    att = grid.attitude
    w = _omega(fam, X, grid.beta, att)
    ok = np.isfinite(w)
    X, w = X[ok], w[ok]
    Q, own = ise_normalized(fam, w, grid.omega_df, grid.c1, grid.c3, include_own=True, **_proc_params(fam, X, att))
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
