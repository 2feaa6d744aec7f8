"""Class grids of the lumped parameter space, spaced by closed-loop performance.

A grid is the DNN's list of classes: each class is one lumped process with
its rule gains, its MRFT oscillation and the J matrix between classes
(``uavsim.tuning.jmatrix``). One versioned JSON file per loop family lives in
``uavsim/tuning/grids/`` and is read by data generation and training.

The inner grids are built by ``uavsim.tuning.grid_design.build_grid`` (``Omega`` levels
spaced by J), reported by ``uavsim.tuning.grid_report``; both names stay importable from here.

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

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.frequency import mrft_prediction_batch
from uavsim.lumped.params import RANGES, LumpedParams, loop_family
from uavsim.tuning.rule import TuningRule

__all__ = ["Grid", "load_grid", "save_grid", "attitude_of", "neighbour_pairs", "GRID_VERSION", "TARGETS"]

GRID_VERSION = 1
#: class-count targets (paper) and neighbour J target
TARGETS = {"attitude": 48, "altitude": 208, "lateral": 15, "J": 1.10}
BOX_AXES = {"attitude": ("T_prop", "T1", "tau"), "altitude": ("T_prop", "T1", "tau"), "lateral": ("T2", "tau")}


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


def content_hash(d: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()


def write_hashed_json(d: dict[str, Any], path: Path) -> str:
    """Write ``d`` with its content hash as JSON atomically (temp file, then ``os.replace``); return the hash."""
    path.parent.mkdir(parents=True, exist_ok=True)
    d = {**d, "hash": content_hash(d)}
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
        if h and h != content_hash(d):
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


# --- the box and its processes (shared by the builds and the reports) ------------------

def log_box(fam: str) -> tuple[np.ndarray, np.ndarray]:
    box = RANGES[fam]
    lo = np.log([box[k][0] for k in BOX_AXES[fam]])
    hi = np.log([box[k][1] for k in BOX_AXES[fam]])
    return lo, hi


def class_omega(fam: str, X: np.ndarray, beta: float, att: dict | None) -> np.ndarray:
    """DF MRFT frequency of points X (P, d) in the family's axes (lateral: over the attitude dict ``att``)."""
    return mrft_prediction_batch(fam, beta, 1.0, K=1.0, **class_process_params(fam, X, att))[0]


def class_process_params(fam: str, X: np.ndarray, att: dict | None) -> dict[str, Any]:
    if fam == "lateral":
        # a lateral grid's attitude PD runs at the control rate (``rate_hz``); older grids' ran continuous
        return {"T_prop": att["T_prop"], "T1": att["T1"], "tau": X[:, 1], "T2": X[:, 0], "tau_in": att["tau_in"],
                "att_kp": att["att_kp"], "att_kd": att["att_kd"], "att_N": 2 * np.pi * att["att_filter_hz"],
                "att_rate_hz": att.get("rate_hz")}
    return {"T_prop": X[:, 0], "T1": X[:, 1], "tau": X[:, 2]}


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


def box_sample(fam: str, rng: np.random.Generator, n: int, corners: bool = False) -> np.ndarray:
    """``n`` log-uniform points of the family's box, (n, d), then its corners if asked (2-d boxes)."""
    lo, hi = log_box(fam)
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
    lo, hi = log_box(fam)
    Z = (np.log(np.column_stack([grid.params[k] for k in BOX_AXES[fam]])) - lo) / (hi - lo)
    across, within = [], []
    for i in range(grid.n):
        d = ((Z - Z[i]) ** 2).sum(1)
        for dl, out in ((-1, across), (1, across), (0, within)):
            m = np.nonzero((grid.level == grid.level[i] + dl) & (np.arange(grid.n) != i))[0]
            if len(m):
                out.append((i, m[np.argmin(d[m])]))
    return np.array(across, int).reshape(-1, 2), np.array(within, int).reshape(-1, 2)


#: names that moved to the build and report modules, still importable from here
_MOVED = {"build_grid": "grid_design", "_design": "grid_design", "_finish": "grid_design", "_kmeans": "grid_design",
          "_calibrate_ratio": "grid_design", "_j_curves": "grid_design", "_RATIOS": "grid_design",
          "grid_report": "grid_report", "coverage": "grid_report", "_neighbour_J": "grid_report",
          "_point_J": "grid_report", "_lateral_report": "grid_report", "_stats": "grid_report",
          "_j_figures": "grid_report"}


def __getattr__(name: str):  # lazy: the build and report modules import this one
    if name in _MOVED:
        import importlib

        return getattr(importlib.import_module(f"uavsim.tuning.{_MOVED[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
