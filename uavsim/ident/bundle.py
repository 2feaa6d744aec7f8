"""The model bundle: an exported network and everything identification needs beside it.

A model folder (``uavsim.learning.export``: ``weights.npz``, ``meta.json``, ...) is
all identification reads. ``meta.json`` carries, written at export time
(``uavsim.learning.bundle.bundle_section``, called by the trainer):

* the class table (``classes``): each class's lumped time parameters, its cycle
  period, and the grid's table of PDs at the control rate (``table_robust_kp``,
  ``table_robust_kd``, ``table_filter_hz``, ``table_omega``, ``table_gain_at_omega``:
  ``uavsim.tuning.table``);
* ``identification``: the control rate of that table, the rule of the grid
  (``beta``, ``pm_deg``, ``gain_scale``), the preprocessing settings (input rate,
  length, cycles, channels) and, for a lateral network, the attitude loop its
  sub-grid closes (the attitude class and the attitude table's PD).

``weights.npz`` carries, beside the network, the class decision's cost matrix
(``J``: the dataset's, rows class answered, columns true class) and the
temperature of its belief, and ``meta.json``'s ``identification`` section the
decision the trainer chose (``class_decision``: ``uavsim.ident.select``); a
folder exported before them decides by argmax only.

So identification never reloads the package grids or tables, nor re-parses a
recipe: a bundle identifies the same way wherever it is copied, and a grid
rebuilt since cannot change its answers. A folder exported before the
``identification`` section existed is read from the same fields at the top of
its ``meta.json`` (inner loops; a lateral network needs the section).

Where folders are found: ``resolve_model_dir`` takes a model folder, or a root
with ``altitude/``, ``attitude/`` and ``lateral/aNN/``; the default root is
``$UAVSIM_MODELS``, else ``training/runs`` under the current directory (where
``uavsim train`` writes from a checkout).

    from uavsim.ident.bundle import load_bundle, resolve_model_dir
    b = load_bundle(resolve_model_dir("altitude", "training/runs"))
    b.family, b.n_classes, b.rate_hz, b.rule.beta
    b.column("table_robust_kp")                 # (n_classes,) unit-gain kp of the table's robust answers
    b.cost, b.temperature                       # J (n_classes, n_classes) of the class decision or None; T
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.formats.session import RELAY_BIAS_TRIMS
from uavsim.learning.bundle import BUNDLE_FORMAT
from uavsim.learning.export import META_FILE, WEIGHTS_FILE, Predictor
from uavsim.tuning.rule import TuningRule

__all__ = ["TABLE_COLUMNS", "PERIOD_RANGE", "ModelBundle", "load_bundle", "default_model_root", "resolve_model_dir",
           "period_bounds"]

#: class-table columns the table path needs (unit-gain PDs at ``rate_hz`` and the gain estimate's reference)
TABLE_COLUMNS = ("table_kp", "table_kd", "table_robust_kp", "table_robust_kd", "table_filter_hz", "table_omega",
                 "table_gain_at_omega")
#: a cycle's period must lie within [PERIOD_RANGE[0] x the classes' shortest, PERIOD_RANGE[1] x their longest]:
#: NP-MRFT lengthens cycles (up to ~1.3x off-grid at 20% noise) but never halves them, which a relay
#: switching on noise does
PERIOD_RANGE = (0.75, 1.5)
_ATTITUDE_KEYS = ("T_prop", "T1", "tau_in", "att_kp", "att_kd", "att_filter_hz")


@dataclass
class ModelBundle:
    """An exported network with what identification needs (module docstring).

    Attributes
    ----------
    dir : Path
        The model folder.
    loop : str
        ``altitude``, ``attitude`` or ``lateral``: the family the network classifies.
    rate_hz : float
        Control rate of the table's PDs, Hz.
    rule : TuningRule
        The grid's (lateral: the sub-grid's) rule; its ``beta`` is the relay's.
    input_length, cycles : int
        Preprocessing: samples of an input at ``input_rate_hz``, cycles per input.
    input_rate_hz : float
        Rate inputs are built at, Hz.
    classes : dict of (n,) float arrays
        The class table.
    attitude : dict or None
        Lateral: the attitude loop under the sub-grid (``T_prop``, ``T1``, ``tau_in`` in s,
        ``att_kp``, ``att_kd`` for the unit-gain attitude process, ``att_filter_hz``, ``att_class``).
    att_class : int or None
        Lateral: the attitude class of the sub-grid.
    predictor : Predictor
        The network (numpy).
    cost : (n, n) float array or None
        ``J`` of the class decision (rows class answered, columns true), from ``weights.npz``;
        None for a folder exported before it.
    temperature : float
        Temperature of the decision's belief ``softmax(a / T)`` (``weights.npz``; 1 where absent).
    decision : str
        The class decision identification makes by default: the trainer's choice, ``bayes``
        where the bundle carries ``J`` and names none, ``argmax`` without ``J``.
    bias_trim : str
        The relay of the network's training runs: ``"duty"`` where it trimmed its bias (their
        cycles are symmetric: ``uavsim.ident.cycle.duty_refusal``), ``"off"`` (also an export
        from before the section said).
    meta : dict
        ``meta.json`` as read.
    """

    dir: Path
    loop: str
    rate_hz: float
    rule: TuningRule
    input_length: int
    cycles: int
    input_rate_hz: float
    classes: dict[str, np.ndarray]
    predictor: Predictor
    meta: dict[str, Any] = field(repr=False)
    attitude: dict[str, float] | None = None
    att_class: int | None = None
    cost: np.ndarray | None = field(default=None, repr=False)
    temperature: float = 1.0
    decision: str = "argmax"
    bias_trim: str = "off"

    @property
    def family(self) -> str:
        return self.loop

    @property
    def n_classes(self) -> int:
        return int(self.predictor.n_classes)

    @functools.cached_property
    def log_cost(self) -> np.ndarray | None:
        """``log`` of the clipped ``cost`` (``uavsim.learning.decision.log_cost``), (n, n), computed once."""
        from uavsim.learning.decision import log_cost

        return None if self.cost is None else log_cost(self.cost, self.n_classes)

    @property
    def has_table(self) -> bool:
        """Whether the class table carries the grid's table of PDs (datasets written since it existed)."""
        return all(k in self.classes for k in TABLE_COLUMNS)

    def column(self, name: str) -> np.ndarray:
        """Class-table column ``name`` (n,), or a one-line error naming the folder."""
        try:
            return self.classes[name]
        except KeyError:
            raise UserError(f"{self.dir / META_FILE}: the class table has no {name!r} (exported from a dataset "
                            "written before the table existed: regenerate the dataset and retrain)") from None

    def period_bounds(self) -> tuple[float, float]:
        """Shortest and longest cycle period (s) this network's classes can produce (``period_bounds``)."""
        P = self.column("period")
        if "period_sim" in self.classes:  # the cycle at the control rate: sampling lengthens the fastest
            P = np.concatenate([P, self.classes["period_sim"][np.isfinite(self.classes["period_sim"])]])
        return period_bounds(P)


def period_bounds(periods) -> tuple[float, float]:
    """Shortest and longest cycle period (s) classes of these periods (s) can produce (``PERIOD_RANGE``)."""
    P = np.asarray(periods, dtype=np.float64)
    return PERIOD_RANGE[0] * float(np.min(P)), PERIOD_RANGE[1] * float(np.max(P))


def default_model_root() -> Path:
    """``$UAVSIM_MODELS``, else ``training/runs`` under the current directory."""
    env = os.environ.get("UAVSIM_MODELS")
    return Path(env) if env else Path("training") / "runs"


def resolve_model_dir(family: str, model_dir: str | os.PathLike | None = None, att_class: int | None = None) -> Path:
    """The exported model folder for a loop family.

    ``model_dir`` may be a model folder itself (holding ``meta.json``) or a root
    with one folder per family (``altitude/``, ``attitude/``, and
    ``lateral/aNN/`` per attitude class ``att_class``); default ``default_model_root()``.
    """
    root = Path(model_dir) if model_dir is not None else default_model_root()
    if (root / META_FILE).is_file():
        return root
    sub = Path(family) / f"a{att_class:02d}" if family == "lateral" and att_class is not None else Path(family)
    if (root / sub / META_FILE).is_file():
        return root / sub
    make = "make train LOOPS=lateral" if family == "lateral" else "make train"
    raise UserError(f"no trained {family} network under {root / sub} (run `{make}` or pass --models DIR)")


_bundles: dict[str, ModelBundle] = {}


def load_bundle(model_dir: str | os.PathLike) -> ModelBundle:
    """Read a model folder (cached per resolved path: identification in a loop reads it once)."""
    d = Path(model_dir)
    key = str(d.resolve())
    if key not in _bundles:
        _bundles[key] = _read_bundle(d)
    return _bundles[key]


def _num(meta: dict, key: str, where: Path, default: float | None = None) -> float:
    v = meta.get(key, default)
    if v is None or not isinstance(v, int | float) or not math.isfinite(float(v)):
        raise UserError(f"{where}: {key!r} missing or not a number")
    return float(v)


def _read_decision(d: Path, n: int) -> tuple[np.ndarray | None, float]:
    """``J`` (n, n) and the temperature of ``weights.npz``: (None, 1) where the folder has none."""
    path = d / WEIGHTS_FILE
    if not path.is_file():
        return None, 1.0
    try:
        with np.load(path, allow_pickle=False) as z:
            J = np.asarray(z["J"], dtype=np.float64) if "J" in z.files else None
            T = float(z["temperature"]) if "temperature" in z.files else 1.0
    except (OSError, ValueError, TypeError) as exc:
        raise UserError(f"{path}: not a weights file ({exc})") from None
    if J is not None and J.shape != (n, n):
        raise UserError(f"{path}: cost matrix J of shape {J.shape}, the network has {n} classes")
    if not (math.isfinite(T) and T > 0):
        raise UserError(f"{path}: temperature {T} is not a positive number")
    return J, T


def _read_bundle(d: Path) -> ModelBundle:
    pred = Predictor(d)
    meta = pred.meta
    where = d / META_FILE
    sec = meta.get("identification")
    if sec is not None and sec.get("format") != BUNDLE_FORMAT:
        raise UserError(f"{where}: identification section {sec.get('format')!r}, expected {BUNDLE_FORMAT!r}")
    loop = meta.get("loop")
    if loop not in ("altitude", "attitude", "lateral"):
        raise UserError(f"{where}: loop {loop!r} is not altitude, attitude or lateral")
    try:
        classes = {k: np.asarray([np.nan if x is None else x for x in v], dtype=np.float64)
                   for k, v in meta["classes"].items()}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise UserError(f"{where}: no readable class table ({exc})") from None
    bad = [k for k, v in classes.items() if v.shape != (pred.n_classes,)]
    if bad:
        raise UserError(f"{where}: class-table columns {bad} do not have {pred.n_classes} entries")
    if sec is None:
        if loop == "lateral":
            raise UserError(f"{where}: a lateral network exported without its identification section (the "
                            "attitude loop under its sub-grid): retrain it")
        # an export from before the section: the same settings at the top of meta.json
        sec = {"rate_hz": meta.get("rate_hz", 200.0),
               "rule": {"beta": meta.get("beta"), "pm_deg": meta.get("pm_deg") or TuningRule().pm_deg,
                        "gain_scale": 1.0},
               "preprocess": {"input_rate_hz": 200.0, "input_length": meta.get("input_length"),
                              "cycles": meta.get("cycles", 1)}}
    rule, pre = sec.get("rule") or {}, sec.get("preprocess") or {}
    r = TuningRule(_num(rule, "beta", where), _num(rule, "pm_deg", where), _num(rule, "gain_scale", where, 1.0))
    L = int(_num(pre, "input_length", where))
    if L != pred.input_length:
        raise UserError(f"{where}: input length {L} in the identification section, the network takes "
                        f"{pred.input_length}")
    att = sec.get("attitude")
    if loop == "lateral":
        if not isinstance(att, dict) or any(k not in att for k in _ATTITUDE_KEYS):
            raise UserError(f"{where}: a lateral bundle needs its attitude loop ({', '.join(_ATTITUDE_KEYS)})")
        att = {k: (int(v) if k == "att_class" else float(v)) for k, v in att.items() if v is not None}
    cost, temperature = _read_decision(d, pred.n_classes)
    decision = ((sec.get("class_decision") or {}).get("decision") or "bayes") if cost is not None else "argmax"
    if decision not in ("bayes", "argmax"):
        raise UserError(f"{where}: class decision {decision!r} is not bayes or argmax")
    bias_trim = (sec.get("relay") or {}).get("bias_trim", "off")
    if bias_trim not in RELAY_BIAS_TRIMS:
        raise UserError(f"{where}: relay bias_trim {bias_trim!r} is not one of {', '.join(RELAY_BIAS_TRIMS)}")
    return ModelBundle(dir=d, loop=loop, rate_hz=_num(sec, "rate_hz", where), rule=r, input_length=L,
                       cycles=int(_num(pre, "cycles", where, 1)),
                       input_rate_hz=_num(pre, "input_rate_hz", where, 200.0), classes=classes, predictor=pred,
                       meta=meta, attitude=att if loop == "lateral" else None, cost=cost, temperature=temperature, decision=decision, bias_trim=bias_trim,
                       att_class=int(meta["att_class"]) if meta.get("att_class") is not None else None)
