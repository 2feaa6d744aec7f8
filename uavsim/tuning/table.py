"""The grids' lookup table: each class's ISE-optimal PD at the control rate.

For every class of a grid (unit gain, K = 1) the table holds the PD that
minimizes the exact step ISE at the control rate (``uavsim.tuning.optimal``:
zero-order hold, the sampled filtered derivative, the derivative filter fixed
by the rule at ``10 Omega`` capped at a quarter of the rate), its ISE, the
rule's ISE at the same rate for comparison, and the relative sensitivity ``J``
between classes recomputed from these gains (``uavsim.tuning.sensitivity``).

The ISE optimum is aggressive (gain margins 1.3-1.5 on the inner loops, 1.03-1.3
on the lateral ones): a neighbour class's optimum can destabilize a process,
most of the lateral neighbour pairs one way. So each class also has a robust
answer, ``robust_kp``/``robust_kd``: the PD of least expected J over the class
and its grid neighbours (``neighbourhoods``; ``uavsim.tuning.robust``), each
neighbour judged with the gain identification would estimate on it for this
class. It costs the class itself about a percent and holds every neighbour
(``J_robust``); it is what ``OptimalTable.gains`` answers by default.

Gains are for K = 1; a process of gain K takes ``kp / K``, ``kd / K`` and the
same filter (``OptimalTable.gains``). The table's J (and the robust answers)
assume identification estimates K as it does (``uavsim.ident``): the measured
response magnitude at the cycle's frequency over the class's own at that same
frequency, ``K_hat = |G(j w)| / |G_class(j w)|`` (the ``"response"`` scaling of
``uavsim.tuning.sensitivity``). The other estimate, against the class's own
magnitude at its nominal MRFT point (``"mrft"``, ``OptimalTable.gain_estimate``),
is biased wherever the NP-MRFT cycle is not at the nominal DF frequency: on 300
off-grid altitude processes under noise, the J-best class with it gave J p95
2.10, with the response estimate 1.012 (``uavsim evaluate``). Tables built
before carry ``scaling = "mrft"``.

Lateral tables have one sub-table per attitude class, and the attitude loop
under each is closed by that attitude class's table PD sampled at the same rate
(the product tunes attitude before lateral, and the rule's attitude PD is
unstable at 200 Hz on the fastest attitude classes). The 200 Hz lateral grid is
designed over exactly that loop (``uavsim.tuning.lateral_grid``), its neighbours
given by the grid (``Grid.neighbours``); a sub-table stores the attitude PD
(``attitude``, with the ``rate_hz`` it is sampled at) and its classes' DF MRFT
frequency ``omega`` at the sub-grid's beta in the sampled loop: lateral data
and identification must close the attitude loop with it too.

Where tables live: the 200 Hz tables are package data
(``uavsim/tuning/grids/optimal-<family>-200hz.json``); a table at another rate is
built on first use and cached in the user's cache directory
(``$UAVSIM_CACHE_DIR``, else ``$XDG_CACHE_HOME/uavsim``, else ``~/.cache/uavsim``), as
``tables/optimal-<family>-<rate>hz-<grid hash>.json``. Every table names the
hash of the grid it belongs to and is refused with another grid.

    from uavsim.tuning.table import load_table
    t = load_table("altitude")                  # 200 Hz, packaged
    t.gains(cls=12, K=2.5)                      # robust answer: {'kp': ..., 'kd': ..., 'derivative_filter_hz': ...}
    t.J.shape, t.J_robust.shape                 # (208, 208), rows answered, columns true
    t100 = load_table("attitude", rate_hz=100)  # built once (seconds), then read from the cache
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.frequency import freq_response_batch
from uavsim.lumped.params import loop_family
from uavsim.tuning.grid import (
    Grid,
    attitude_of,
    load_grid,
    neighbour_pairs,
    read_hashed_json,
    sub_of,
    write_hashed_json,
)
from uavsim.tuning.optimal import DEFAULT_RATE_HZ, FILTER_CAP_FRACTION, optimal_gains
from uavsim.tuning.robust import robust_gains
from uavsim.tuning.sensitivity import estimated_gain, table_j_matrix

__all__ = ["TABLE_FORMAT", "TABLE_VERSION", "OptimalTable", "build_table", "load_table", "save_table",
           "table_path", "cache_dir", "lateral_attitude", "neighbourhoods"]

TABLE_FORMAT = "uavsim-optimal-table"
TABLE_VERSION = 1
_FILTER_RULE = (f"N = min(10 Omega, 2 pi {FILTER_CAP_FRACTION} rate), Omega the DF MRFT frequency at the grid's beta")


def _rate_tag(rate_hz: float) -> str:
    return f"{float(rate_hz):g}".replace(".", "p")


def cache_dir() -> Path:
    """The user's cache directory for tables at other rates (see module docstring)."""
    if os.environ.get("UAVSIM_CACHE_DIR"):
        return Path(os.environ["UAVSIM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "uavsim"


def _packaged(family: str, rate_hz: float) -> Path:
    return Path(str(resources.files("uavsim.tuning"))) / "grids" / f"optimal-{family}-{_rate_tag(rate_hz)}hz.json"


def table_path(family: str, rate_hz: float = DEFAULT_RATE_HZ, grid_hash: str | None = None) -> Path:
    """Where the table of a family at a rate is read from: package data at 200 Hz, else the cache."""
    fam = loop_family(family)
    if float(rate_hz) == DEFAULT_RATE_HZ:
        return _packaged(fam, rate_hz)
    gh = (grid_hash or load_grid(fam).hash)[:16]
    return cache_dir() / "tables" / f"optimal-{fam}-{_rate_tag(rate_hz)}hz-{gh}.json"


@dataclass
class OptimalTable:
    """ISE-optimal PDs of a grid's classes at one control rate (see module docstring).

    Arrays have shape (n,) (``J``: (n, n), rows: class answered, columns: true class).

    Attributes
    ----------
    family : str
    rate_hz : float
    grid_hash : str
        Hash of the grid file the classes come from.
    kp, kd : unit-gain (K = 1) PD gains
    derivative_filter_hz : the filter, Hz
    ise : optimal step ISE (K = 1), output^2 s
    rule_ise : the grid's rule gains' ISE at ``rate_hz`` (inf: unstable there)
    omega : DF MRFT frequency at the grid's beta, rad/s (the filter's and the gain estimate's frequency)
    gain_at_omega : ``|G(j omega)|`` of the unit-gain class (``gain_estimate``)
    J : relative sensitivity between the classes at ``rate_hz`` (class ``i``'s optimal gains on class ``j``)
    robust_kp, robust_kd : the robust answer (unit gain): least expected J over the class and its
        grid neighbours (``neighbourhoods``, ``uavsim.tuning.robust``), same filter
    J_robust : J of the robust answers (class ``i``'s robust gains on class ``j`` against ``j``'s optimum)
    scaling : the gain estimate J assumes (``uavsim.tuning.sensitivity.SCALINGS``)
    beta, pm_deg, gain_scale : the grid's (sub-grid's) rule
    built : how and when it was built
    attitude : lateral sub-tables: the attitude class and the attitude PD closing it
    sub : lateral: one sub-table per attitude class
    """

    family: str
    rate_hz: float
    grid_hash: str
    kp: np.ndarray
    kd: np.ndarray
    derivative_filter_hz: np.ndarray
    ise: np.ndarray
    rule_ise: np.ndarray
    omega: np.ndarray
    gain_at_omega: np.ndarray
    J: np.ndarray
    robust_kp: np.ndarray
    robust_kd: np.ndarray
    J_robust: np.ndarray
    beta: float
    pm_deg: float
    gain_scale: float
    built: dict[str, Any]
    scaling: str = "mrft"
    attitude: dict[str, float] | None = None
    sub: list[OptimalTable] = field(default_factory=list)
    version: int = TABLE_VERSION
    hash: str = ""

    @property
    def n(self) -> int:
        return int(self.kp.shape[0])

    @property
    def N(self) -> np.ndarray:
        """Derivative filters, rad/s."""
        return 2.0 * math.pi * self.derivative_filter_hz

    @property
    def pd_hash(self) -> str:
        """Hash of what a loop closed by this table's PDs depends on: grid, rate, ``kp``, ``kd``, filters.

        The lateral grid and table are designed over the attitude table's PDs; its J, robust
        answers or gain estimate may change without touching them.
        """
        from uavsim.tuning.grid import content_hash

        def arr(x):
            return [float(f"{v:.10g}") for v in np.asarray(x, float).ravel()]

        return content_hash({"grid_hash": self.grid_hash, "rate_hz": float(self.rate_hz), "kp": arr(self.kp),
                             "kd": arr(self.kd), "derivative_filter_hz": arr(self.derivative_filter_hz)})

    def lateral(self, att_class: int) -> OptimalTable:
        """Sub-table of attitude class ``att_class`` (lateral tables only)."""
        return sub_of(self.sub, att_class, f"the {self.family} table")

    def gains(self, cls: int, K: float = 1.0, robust: bool = True) -> dict[str, float]:
        """Gains of class ``cls`` for a process of gain ``K``: ``kp / K``, ``kd / K``, the filter (Hz).

        ``robust`` (default): the robust answer (``robust_kp``, ``robust_kd``), which a one-level miss
        of the class does not destabilize; else the class's own ISE optimum (``kp``, ``kd``).
        """
        if self.sub:
            raise UserError("a lateral table has one sub-table per attitude class: use table.lateral(a).gains(i, K)")
        if not 0 <= cls < self.n:
            raise UserError(f"class {cls} out of range 0..{self.n - 1}")
        if not (math.isfinite(K) and K > 0):
            raise UserError(f"process gain K must be finite and > 0, got {K!r}")
        kp, kd = (self.robust_kp, self.robust_kd) if robust else (self.kp, self.kd)
        return {"kp": float(kp[cls]) / K, "kd": float(kd[cls]) / K,
                "derivative_filter_hz": float(self.derivative_filter_hz[cls])}

    def gain_estimate(self, cls: int, response_magnitude: float) -> float:
        """``K_hat = |G(j w)| / gain_at_omega[cls]``: the estimate at the class's nominal MRFT point.

        Tables with ``scaling = "response"`` assume the gain fitted at the cycle's frequency
        instead (``uavsim.ident``); this one is kept for comparison (``uavsim evaluate``).

        ``response_magnitude``: the measured ``|G(j w)|`` at the cycle's frequency (output units
        per command unit, the hold removed: ``uavsim.data.preprocess.process_response``).
        """
        if self.sub:
            raise UserError("a lateral table has one sub-table per attitude class: use table.lateral(a)")
        if not 0 <= cls < self.n:
            raise UserError(f"class {cls} out of range 0..{self.n - 1}")
        return float(response_magnitude) / float(self.gain_at_omega[cls])

    # --- serialization ------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        def arr(x, nd=10):
            return [None if not np.isfinite(v) else float(f"{v:.{nd}g}") for v in np.asarray(x, float).ravel()]

        d: dict[str, Any] = {"format": TABLE_FORMAT, "version": self.version, "family": self.family,
                             "rate_hz": self.rate_hz, "grid_hash": self.grid_hash, "beta": self.beta,
                             "pm_deg": self.pm_deg, "gain_scale": self.gain_scale, "scaling": self.scaling,
                             "built": self.built}
        if self.sub:
            d["sub"] = [s.to_dict() for s in self.sub]
            return d
        d.update({"kp": arr(self.kp), "kd": arr(self.kd), "derivative_filter_hz": arr(self.derivative_filter_hz),
                  "ise": arr(self.ise), "rule_ise": arr(self.rule_ise), "omega": arr(self.omega),
                  "gain_at_omega": arr(self.gain_at_omega), "robust_kp": arr(self.robust_kp),
                  "robust_kd": arr(self.robust_kd),
                  "J": [arr(row, 6) for row in self.J], "J_robust": [arr(row, 6) for row in self.J_robust]})
        if self.attitude is not None:
            d["attitude"] = self.attitude
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> OptimalTable:
        def arr(x):
            return np.array([np.inf if v is None else v for v in x], dtype=np.float64)

        common = {k: d[k] for k in ("family", "rate_hz", "grid_hash", "beta", "pm_deg", "gain_scale", "scaling", "built",
                                    "version")}
        if "sub" in d:
            empty = np.zeros(0)
            t = cls(kp=empty, kd=empty, derivative_filter_hz=empty, ise=empty, rule_ise=empty, omega=empty,
                    gain_at_omega=empty, J=np.zeros((0, 0)), robust_kp=empty, robust_kd=empty,
                    J_robust=np.zeros((0, 0)), **common)
            t.sub = [cls.from_dict(s) for s in d["sub"]]
            return t
        return cls(kp=arr(d["kp"]), kd=arr(d["kd"]), derivative_filter_hz=arr(d["derivative_filter_hz"]),
                   ise=arr(d["ise"]), rule_ise=arr(d["rule_ise"]), omega=arr(d["omega"]),
                   gain_at_omega=arr(d["gain_at_omega"]), robust_kp=arr(d["robust_kp"]), robust_kd=arr(d["robust_kd"]),
                   J_robust=np.array([arr(r) for r in d["J_robust"]]).reshape(len(d["kp"]), len(d["kp"])),
                   J=np.array([arr(r) for r in d["J"]]).reshape(len(d["kp"]), len(d["kp"])),
                   attitude=d.get("attitude"), **common)


def save_table(table: OptimalTable, path: str | os.PathLike | None = None) -> Path:
    """Write the table as JSON atomically; default path: ``table_path`` (package data at 200 Hz)."""
    path = Path(path) if path is not None else table_path(table.family, table.rate_hz, table.grid_hash)
    table.hash = write_hashed_json(table.to_dict(), path)
    return path


def _read(path: Path) -> OptimalTable:
    t, h = read_hashed_json(path, "table", lambda d: None if (d.get("format"), d.get("version")) == (
        TABLE_FORMAT, TABLE_VERSION) else f"is not a {TABLE_FORMAT} version {TABLE_VERSION} file", OptimalTable.from_dict)
    t.hash = h
    return t


def load_table(family: str, rate_hz: float = DEFAULT_RATE_HZ, *, path: str | os.PathLike | None = None,
               grid: Grid | None = None, build: bool = True, log=None) -> OptimalTable:
    """The table of a family at a control rate.

    Parameters
    ----------
    family : str
        Loop or family name.
    rate_hz : float
        Control rate, Hz: 200 Hz is packaged; another rate is read from the cache, or built
        (``build_table``) and cached there when ``build`` is true.
    path : path or None
        Read this file instead.
    grid : Grid or None
        The grid the table must belong to (default: the packaged grid of the family).
    build : bool
        Build and cache a missing table at a rate other than 200 Hz.
    log : callable or None
        Progress lines of a build.
    """
    fam = loop_family(family)
    grid = grid or load_grid(fam)
    if path is not None:
        p = Path(path)
    else:
        p = table_path(fam, rate_hz, grid.hash)
    if not p.exists():
        if path is not None or float(rate_hz) == DEFAULT_RATE_HZ or not build:
            raise UserError(f"no {fam} table at {p} (run `uavsim grid table --loop {fam} --rate {rate_hz:g}`)")
        save_table(build_table(fam, rate_hz, grid=grid, log=log), p)
        if log:
            log(f"cached the {fam} table at {rate_hz:g} Hz in {p}")
    t = _read(p)
    if t.grid_hash != grid.hash:
        raise UserError(f"table file {p} belongs to another {fam} grid (hash {t.grid_hash[:12]}, grid "
                        f"{grid.hash[:12]}): rebuild it with `uavsim grid table --loop {fam} --rate {t.rate_hz:g}`")
    if float(t.rate_hz) != float(rate_hz):
        raise UserError(f"table file {p} is for {t.rate_hz:g} Hz, not {rate_hz:g} Hz")
    return t


def _inner_params(grid: Grid) -> dict[str, np.ndarray]:
    return {k: np.asarray(grid.params[k], dtype=np.float64) for k in ("T_prop", "T1", "tau")}


def neighbourhoods(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Each class with its grid neighbours (``uavsim.tuning.grid.neighbour_pairs``, both ways).

    Returns ``(answer, model)`` index arrays: class ``answer[k]``'s neighbourhood holds ``model[k]``
    (itself included), sorted by answer.
    """
    across, within = neighbour_pairs(grid)
    pr = np.vstack([np.column_stack([np.arange(grid.n)] * 2), across, within, across[:, ::-1], within[:, ::-1]])
    pr = np.unique(pr, axis=0)
    return pr[:, 0], pr[:, 1]


def build_flat_table(fam: str, rate_hz: float, grid: Grid, cparams: dict[str, Any], built: dict[str, Any],
                attitude: dict | None = None, scaling: str = "response") -> OptimalTable:
    rule = grid.rule
    g = optimal_gains(fam, rate_hz, rule=rule, K=1.0, **cparams)
    if not np.all(np.isfinite(g.ise)):
        bad = np.flatnonzero(~np.isfinite(g.ise)).tolist()
        raise UserError(f"{fam}: no stable PD found at {rate_hz:g} Hz for classes {bad}")
    J = table_j_matrix(fam, rate_hz, cparams, g.kp, g.kd, g.N, g.ise, g.omega, scaling=scaling)
    gw = np.abs(freq_response_batch(fam, g.omega[:, None], K=1.0, **cparams)[:, 0])
    # the robust answer: least expected J over the class and its neighbours, each judged with the
    # gain identification would estimate on it for this class
    ans, mod = neighbourhoods(grid)
    pick = {k: (np.asarray(v)[mod] if np.size(v) > 1 else v) for k, v in cparams.items()}
    ansp = {k: (np.asarray(v)[ans] if np.size(v) > 1 else v) for k, v in cparams.items()}
    K_hat = estimated_gain(fam, g.omega[mod], {"K": 1.0, **pick}, ansp, g.omega[ans], scaling)
    r = robust_gains(fam, rate_hz, models={"K": 1.0, **pick}, group=ans, N=g.N, scale=1.0 / K_hat,
                     q_opt=g.ise[mod], kp_opt=g.kp[mod], kd_opt=g.kd[mod])
    Jr = table_j_matrix(fam, rate_hz, cparams, r["kp"], r["kd"], g.N, g.ise, g.omega, scaling=scaling)
    return OptimalTable(family=fam, rate_hz=float(rate_hz), grid_hash=grid.hash, kp=g.kp, kd=g.kd,
                        derivative_filter_hz=g.derivative_filter_hz, ise=g.ise, rule_ise=g.rule_ise, omega=g.omega,
                        gain_at_omega=gw, J=J, robust_kp=r["kp"], robust_kd=r["kd"], J_robust=Jr, beta=rule.beta,
                        pm_deg=rule.pm_deg, gain_scale=rule.gain_scale, built=built, scaling=scaling,
                        attitude=attitude)


def grid_gain_scaling(grid: Grid) -> str:
    """The gain estimate a lateral grid was designed with, read from its ``built["method"]``
    (grids designed before it was written there used the MRFT-point estimate, ``"mrft"``)."""
    method = str(grid.built.get("method", ""))
    return "mrft" if "mrft gain estimate" in method or "gain estimate" not in method else "response"


def lateral_attitude(att_table: OptimalTable, att_grid: Grid, a: int) -> dict[str, float]:
    """Attitude class ``a`` with the table's attitude PD (unit gain) that closes the lateral loop over it.

    Keys as the lateral grids' ``attitude`` (``uavsim.tuning.grid.attitude_of``: ``T_prop``, ``T1``,
    ``tau_in``, ``att_kp``, ``att_kd``, ``att_filter_hz``, ``att_class``, and ``rate_hz``, the rate the PD
    is sampled at).
    """
    return attitude_of(att_grid, a, att_table)


def build_table(family: str, rate_hz: float = DEFAULT_RATE_HZ, *, grid: Grid | None = None, log=None) -> OptimalTable:
    """Optimize every class of a grid at ``rate_hz`` and compute the table's J (unsaved).

    A lateral table needs the attitude table at the same rate (loaded, or built and cached).
    """
    from uavsim import __version__ as tool_version

    fam = loop_family(family)
    grid = grid or load_grid(fam)
    t0 = time.time()
    built: dict[str, Any] = {"date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
                             "tool_version": tool_version, "filter": _FILTER_RULE,
                             "step": "unit reference step; the PD starts at the step (raw_0 = 0)",
                             "gain_estimate": "K_hat = |G(j w)| / |G_class(j w)| at the cycle's w (response scaling)",
                             "robust": "least expected J over the class and its grid neighbours, equal weights"}
    if fam != "lateral":
        t = build_flat_table(fam, rate_hz, grid, _inner_params(grid), built)
        built["build_time_s"] = round(time.time() - t0, 1)
        return t
    att_grid = load_grid("attitude")
    att_table = load_table("attitude", rate_hz, grid=att_grid, log=log)
    design = grid.built.get("attitude_pd_hash")
    if design is not None and float(grid.built.get("rate_hz", math.nan)) == float(rate_hz) and design != att_table.pd_hash:
        raise UserError(f"the lateral grid was designed over other attitude PDs (hash {design[:12]}, table "
                        f"{att_table.pd_hash[:12]}): rebuild it with `uavsim grid build --loop lateral`")
    built.update(attitude_pd_hash=att_table.pd_hash, attitude_grid_hash=att_grid.hash,
                 attitude_loop="each attitude class closed by its attitude table PD at the same rate")
    subs = []
    scaling = grid_gain_scaling(grid)  # a grid's table keeps the gain estimate its cover was chosen with
    for a, sg in enumerate(grid.sub):
        att = lateral_attitude(att_table, att_grid, a)
        cparams = {"T_prop": att["T_prop"], "T1": att["T1"], "tau": np.asarray(sg.params["tau"], float),
                   "T2": np.asarray(sg.params["T2"], float), "tau_in": att["tau_in"], "att_kp": att["att_kp"],
                   "att_kd": att["att_kd"], "att_N": 2.0 * math.pi * att["att_filter_hz"], "att_rate_hz": att["rate_hz"]}
        ts = time.time()
        subs.append(build_flat_table("lateral", rate_hz, sg, cparams, {"build_time_s": 0.0}, att, scaling=scaling))
        subs[-1].grid_hash = grid.hash
        subs[-1].built["build_time_s"] = round(time.time() - ts, 1)
        if log:
            log(f"lateral sub-table {a + 1}/{len(grid.sub)}: {subs[-1].n} classes ({time.time() - t0:.0f} s)")
    r = grid.rule
    t = OptimalTable(family=fam, rate_hz=float(rate_hz), grid_hash=grid.hash, kp=np.zeros(0), kd=np.zeros(0),
                     derivative_filter_hz=np.zeros(0), ise=np.zeros(0), rule_ise=np.zeros(0), omega=np.zeros(0),
                     gain_at_omega=np.zeros(0), J=np.zeros((0, 0)), robust_kp=np.zeros(0), robust_kd=np.zeros(0),
                     J_robust=np.zeros((0, 0)), beta=r.beta, pm_deg=r.pm_deg, gain_scale=r.gain_scale, built=built, sub=subs)
    built["build_time_s"] = round(time.time() - t0, 1)
    return t

