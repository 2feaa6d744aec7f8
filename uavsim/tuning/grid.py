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

* each attitude class has its own rule ``(beta, pm, gain_scale)``
  (``choose_lateral_rule``, ``uavsim.tuning.search.search_rule``): the candidate
  whose own-loop controllers keep the most of a box sample stable, then the
  smallest worst ISE deterioration against the ISE-optimal PD. The lateral MRFT
  frequency sits on the resonance of the closed attitude loop (pm 20 deg), where
  ``|G|`` still rises above ``Omega``: the classic rule (``gain_scale`` 1, crossover
  at ``Omega``) then has a second crossover past -180 deg, and no ``(beta, pm)`` in
  the authors' bounds keeps more than about half of the box stable over the slowest
  attitude classes. A loop gain of 0.5-0.7 at ``Omega`` keeps all of it stable
  with a worst deterioration of about 1.2-1.5; the sub-grid's ``beta``/``pm_deg``/
  ``gain_scale``/``c1``/``c3`` are its own;
* the J sensitivity to an Omega mismatch varies tenfold along a lateral box, so
  levels are equally spaced in the local J-distance (``_j_distance``), not in one
  Omega ratio, and capped at 15% above the class target;
* processes their own rule controller cannot stabilize (Nyquist test) have no
  finite own ISE, so J is undefined for them: they are excluded from the design
  and from coverage, and ``built["stable_fraction"]`` says how much of the box is
  left. Nyquist claims are checked by time simulation in the build
  (``step_tail``: each sub-grid's fastest class must settle, sampled unstable
  points must diverge; counts in ``built["time_check"]``).

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
                   gain_scale=float(d.get("gain_scale", 1.0)), **a, **common)


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


def _j_distance(fam: str, X: np.ndarray, w: np.ndarray, c1: float, c3: float, target: float, att,
                n_calib: int) -> tuple[np.ndarray, float]:
    """Position of each process along log Omega in units of the local J-spaced level step.

    How fast J grows with an Omega mismatch varies along a lateral box by a factor
    of ten (fastest near the attitude resonance, at the top of the Omega range),
    so one level ratio for the whole range leaves neighbours far from the
    target J at both ends. The local ratio ``r(Omega)`` at which a process's
    symmetric J reaches ``target`` is measured at ``n_calib`` processes spread
    evenly over log Omega, and ``z = integral d ln(Omega) / ln r(Omega)``
    (piecewise-linear ``ln r``, constant beyond the ends): unit steps in ``z`` are
    J-spaced levels.

    Returns
    -------
    z : ndarray (P,)
        Level coordinate of each process (0 at the lowest Omega).
    r : float
        Median local ratio (for the report).
    """
    lw = np.log(w)
    marks = np.linspace(lw.min(), lw.max(), n_calib)
    idx = np.unique(np.argmin(np.abs(lw[:, None] - marks[None, :]), axis=0))
    Js = np.maximum.accumulate(_j_curves(fam, X[idx], w[idx], c1, c3, att), axis=1)  # J grows with the mismatch
    lr = np.array([np.interp(math.log(target), np.log(J), np.log(_RATIOS)) for J in Js])
    order = np.argsort(lw[idx])
    dense = np.linspace(lw.min(), lw.max(), 512)
    inv = 1.0 / np.interp(dense, lw[idx][order], lr[order])
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(dense))])
    return np.interp(lw, dense, cum), float(np.exp(np.median(lr)))


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
            max_levels: int | None = None, adaptive: bool = False) -> dict[str, Any]:
    """Sample the box, place the Omega levels and pick the classes (module docstring, steps 1-4).

    ``adaptive``: levels equally spaced in the local J-distance ``_j_distance``
    (lateral) instead of one calibrated Omega ratio (inner loops, whose J
    sensitivity is nearly uniform). ``max_levels`` caps the level count.
    """
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
    if adaptive:
        z, r = _j_distance(fam, X, w, c1, c3, target_J, att, n_calib)
        unit = 1.0  # z is in level steps already
    else:
        r = _calibrate_ratio(fam, X[:n_calib], w[:n_calib], c1, c3, target_J, att)
        z, unit = np.log(w), math.log(r)
    zmin, zmax = z.min(), z.max()
    n_lev = max(1, int(math.ceil((zmax - zmin) / unit - 1e-9)))
    if max_levels is not None:
        # a class budget smaller than the J-spaced level count: wider levels, larger neighbour J
        n_lev = min(n_lev, max_levels)
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
    # level_step: the mean Omega ratio between adjacent levels
    level_step = math.exp(step) if not adaptive else float((w.max() / w.min()) ** (1.0 / n_lev))
    return {"X": X[chosen], "level": np.array(levels), "ratio": r, "n_levels": n_lev, "level_step": level_step,
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
                beta=rule.beta, pm_deg=rule.pm_deg, c1=c1, c3=c3, built=built, level=design["level"],
                gain_scale=rule.gain_scale, attitude=att)


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


def attitude_of(att_grid: Grid, a: int) -> dict[str, float]:
    """The attitude class ``a`` as the dict a lateral sub-grid stores (unit-gain rule PD)."""
    return {"T_prop": float(att_grid.params["T_prop"][a]), "T1": float(att_grid.params["T1"][a]),
            "tau_in": float(att_grid.params["tau"][a]), "att_kp": float(att_grid.kp[a]), "att_kd": float(att_grid.kd[a]),
            "att_filter_hz": float(att_grid.derivative_filter_hz[a]), "att_class": a}


def _box_sample(fam: str, rng: np.random.Generator, n: int, corners: bool = False) -> np.ndarray:
    """``n`` log-uniform points of the family's box, (n, d), then its corners if asked (2-d boxes)."""
    lo, hi = _log_box(fam)
    X = np.exp(lo + (hi - lo) * rng.random((n, len(lo))))
    if corners:
        X = np.vstack([X, np.exp(np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]]))])
    return X


def choose_lateral_rule(att: dict, rng: np.random.Generator, n_det: int = 26, n_stable: int = 150,
                        tol: float = 0.0) -> dict[str, Any]:
    """Tuning rule ``(beta, pm, gain_scale)`` of the lateral loop over one attitude class.

    ``uavsim.tuning.search.search_rule`` on a log-uniform sample of the (T2, tau_out)
    box: ``n_det`` points plus the four corners carry the ISE deterioration against
    the ISE-optimal PD (filter at 10x the MRFT frequency at the default beta), and
    ``n_stable`` more points only the stability count. The rule that keeps the
    most of the sample stable under its own controller, then has the smallest
    worst deterioration, wins: a lateral rule must first be stable over the box
    (J and the class design are undefined where it is not).

    Returns
    -------
    dict: ``beta``, ``pm_deg``, ``gain_scale``, ``stable_fraction`` (of the whole sample),
    ``worst_deterioration`` (ratio, None if infinite), ``n_evaluated``, ``top``, ``n_points``.
    """
    from uavsim.tuning.search import optimal_pd_batch, search_rule

    Xd = _box_sample("lateral", rng, n_det, corners=True)
    X = np.vstack([Xd, _box_sample("lateral", rng, n_stable)])
    pd = {"K": 1.0, **_proc_params("lateral", Xd, att)}
    ref = TuningRule(DEFAULT_BETA, DEFAULT_PM_DEG).gains_batch("lateral", **pd)
    q_opt = optimal_pd_batch("lateral", pd, ref["N"], ref["omega"], ref["gain_at_omega"])
    q_ref = np.concatenate([q_opt, np.full(n_stable, np.nan)])  # the stability-only points have no reference
    res = search_rule("lateral", {"K": 1.0, **_proc_params("lateral", X, att)}, q_ref, tol=tol)
    res["n_points"] = len(X)
    return res


def step_tail(points: list[tuple[dict, TuningRule, np.ndarray]], periods: float = 30.0, dt: float = 1e-3) -> np.ndarray:
    """Time-domain check of Nyquist claims: the step error's envelope late in a simulation, (m,).

    ``points``: (attitude dict, rule, x = (T2, tau_out)). Each process is
    simulated (``uavsim.lumped.simulate.simulate_pd_step_batch``, sampled PD at
    ``dt`` s) under its own rule controller for ``periods`` periods of the slowest
    MRFT frequency in the batch; returns ``max |e|`` over the last third (unit step;
    inf if the simulation overflowed). A stable loop has settled (well below 1); a
    diverging one exceeds 10.
    """
    from uavsim.lumped.simulate import simulate_pd_step_batch

    if not points:
        return np.zeros(0)
    cols: dict[str, list] = {}
    gains: dict[str, list] = {"kp": [], "kd": [], "N": [], "omega": []}
    for att, rule, x in points:
        pp = _proc_params("lateral", np.asarray(x, float)[None, :], att)
        g = rule.gains_batch("lateral", K=1.0, **pp)
        for k, v in pp.items():
            cols.setdefault(k, []).append(float(np.asarray(v).reshape(-1)[0]))
        for k in gains:
            gains[k].append(float(g[k][0]))
    steps = int(periods * 2 * np.pi / min(gains["omega"]) / dt)
    with np.errstate(over="ignore", invalid="ignore"):
        res = simulate_pd_step_batch("lateral", np.array(gains["kp"]), np.array(gains["kd"]), np.array(gains["N"]), dt,
                                     steps, K=1.0, **{k: np.array(v) for k, v in cols.items()})
    tail = np.abs(res["e"][:, -steps // 3:])
    return np.where(np.isfinite(tail).all(axis=1), np.nan_to_num(tail, nan=np.inf).max(axis=1), np.inf)


def _time_checks(att: dict, sub: Grid, rng: np.random.Generator) -> list[tuple[dict, TuningRule, np.ndarray, bool]]:
    """Points of one attitude class to check in time: its fastest class (nearest the attitude
    resonance: claimed stable) and up to two sampled points its rule leaves unstable."""
    rule = sub.rule
    i = int(np.argmax(sub.omega_df))
    out = [(att, rule, np.array([sub.params["T2"][i], sub.params["tau"][i]]), True)]
    Xs = _box_sample("lateral", rng, 200)
    ws = _omega("lateral", Xs, rule.beta, att)
    fin = np.isfinite(ws)
    bad = np.flatnonzero(~own_loop_stable("lateral", Xs[fin], ws[fin], rule, att))[:2]
    return out + [(att, rule, Xs[fin][j], False) for j in bad]


def _build_lateral(rule: TuningRule, rng: np.random.Generator, t0: float, built: dict[str, Any], n_target: int,
                   target_J: float, log) -> Grid:
    """One sub-grid per attitude class, each with its own rule, over its stable part of the box."""
    att_grid = load_grid("attitude")
    # levels may exceed the class target by 15% (the inner grids' count tolerance) before they widen
    max_levels = int(1.15 * n_target)
    built.update(n_target=n_target, attitude_hash=att_grid.hash, max_levels=max_levels,
                 method="per attitude class: (beta, pm, gain_scale) by stable share then worst ISE deterioration "
                        "(search_rule); omega levels equally spaced in the local J-distance (_j_distance) + k-means "
                        "on iso-Omega slabs over the points stable under their own rule")
    subs, checks = [], []
    for a in range(att_grid.n):
        att = attitude_of(att_grid, a)
        choice = choose_lateral_rule(att, rng)
        sub_rule = TuningRule(choice["beta"], choice["pm_deg"], choice["gain_scale"])
        d = _design("lateral", n_target, sub_rule, rng, 800, target_J, att=att, n_calib=24, stable_only=True,
                    max_levels=max_levels, adaptive=True)
        sb = {"level_ratio": d["ratio"], "n_levels": d["n_levels"], "level_step": d["level_step"],
              "omega_range": d["omega_range"], "stable_fraction": d["stable_fraction"], "rule_choice": choice}
        # the lateral response rolls off at least as 1/w^3: 150 odd harmonics are plenty
        subs.append(_finish("lateral", "lateral", d, sub_rule, att, sb, cycle_kw={"n_harm": 150, "n_t": 1000}))
        checks += _time_checks(att, subs[-1], rng)
        if log:
            log(f"lateral sub-grid {a + 1}/{att_grid.n}: beta {sub_rule.beta}, pm {sub_rule.pm_deg}, gain scale "
                f"{sub_rule.gain_scale}, {subs[-1].n} classes, {100 * d['stable_fraction']:.0f}% of the box stable "
                f"({time.time() - t0:.0f} s)")
    tail = step_tail([c[:3] for c in checks])
    claim = np.array([c[3] for c in checks])
    built["time_check"] = {"n_stable_claims": int(claim.sum()), "n_settled": int(np.sum(claim & (tail < 0.05))),
                           "max_tail_stable": float(tail[claim].max()), "n_unstable_claims": int((~claim).sum()),
                           "n_diverged": int(np.sum(~claim & (tail > 10.0)))}
    built["lateral_rules"] = [[s.beta, s.pm_deg, s.gain_scale] for s in subs]
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
    """Worst-case J between random box points and the class each would be assigned (``_point_J``).

    Lateral sub-grids also report ``stable_fraction`` (points stable under their own
    rule, the ones J is defined for) and ``assigned_stable_fraction``.
    """
    best, info = _point_J(grid, n_points, seed)
    out = _j_figures(best)
    if loop_family(grid.loop) == "lateral":
        out.update(stable_fraction=info["stable_fraction"], assigned_stable_fraction=info["assigned_stable_fraction"])
    return out


def _neighbour_J(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Symmetrized J of the neighbour pairs across and within Omega levels."""
    Js = symmetrize(grid.J)
    across, within = neighbour_pairs(grid)
    return (Js[across[:, 0], across[:, 1]] if len(across) else np.zeros(0),
            Js[within[:, 0], within[:, 1]] if len(within) else np.zeros(0))


def _lateral_report(grid: Grid, n_points: int, seed: int) -> dict[str, Any]:
    """Figures of a lateral grid pooled over its sub-grids (``n_points`` in all, at least)."""
    per = max(int(math.ceil(n_points / len(grid.sub))), 10)
    across, within, best, st, ast, n_s = [], [], [], [], [], []
    for k, s in enumerate(grid.sub):
        ja, jw = _neighbour_J(s)
        b, info = _point_J(s, per, seed + k)
        across.append(ja)
        within.append(jw)
        best.append(b)
        st.append(info["stable_fraction"])
        ast.append(info["assigned_stable_fraction"])
        n_s.append(info["n_sampled"])
    across, within, best = (np.concatenate(v) for v in (across, within, best))
    n_s = np.array(n_s, float)
    rules: dict[str, int] = {}
    for s in grid.sub:
        key = f"beta {s.beta:g} pm {s.pm_deg:g} scale {s.gain_scale:g}"
        rules[key] = rules.get(key, 0) + 1
    sf = [s.built.get("stable_fraction", float("nan")) for s in grid.sub]
    return {
        "loop": grid.loop, "version": grid.version, "hash": grid.hash,
        "n_subgrids": len(grid.sub), "n_classes_total": int(sum(s.n for s in grid.sub)),
        "n_classes_min": int(min(s.n for s in grid.sub)), "n_classes_max": int(max(s.n for s in grid.sub)),
        "n_levels_min": int(min(s.built.get("n_levels", 0) for s in grid.sub)),
        "n_levels_max": int(max(s.built.get("n_levels", 0) for s in grid.sub)),
        "neighbour_J_across_levels": {**_stats(across), "median": float(np.median(across)) if len(across) else float("nan")},
        "neighbour_J_within_level": {**_stats(within), "median": float(np.median(within)) if len(within) else float("nan")},
        "coverage": {**_j_figures(best), "n_sampled": int(n_s.sum()),
                     # pooled over the sub-grids' points (each sub-grid is an equal share of the sample)
                     "stable_fraction": float(np.dot(st, n_s) / n_s.sum()),
                     "assigned_stable_fraction": float(np.dot(ast, n_s) / n_s.sum())},
        "design_stable_fraction_min": float(np.min(sf)),
        "rules": "; ".join(f"{k}: {v}" for k, v in sorted(rules.items(), key=lambda kv: -kv[1])),
        "gain_scale_range": [float(min(s.gain_scale for s in grid.sub)), float(max(s.gain_scale for s in grid.sub))],
        "build_time_s": grid.built.get("build_time_s"), "built": grid.built,
    }


def grid_report(grid: Grid, n_points: int = 2000, seed: int = 1) -> dict[str, Any]:
    """Counts, neighbour-J statistics, coverage and build figures of a grid.

    A lateral grid pools its sub-grids: neighbour J over all their pairs, coverage
    over ``ceil(n_points / 48)`` points of each sub-grid's box, and the rule
    ``(beta, pm, gain_scale)`` of each attitude class counted in ``rules``.
    """
    if grid.sub:
        return _lateral_report(grid, n_points, seed)
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
