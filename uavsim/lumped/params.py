"""Lumped process parameters of the multirotor loops and their ranges.

The paper (eq. 6-7) describes every loop by a handful of lumped parameters:

    inner (attitude, altitude):  G(s) = K e^{-tau s} / (s (T_prop s + 1)(T1 s + 1))
    lateral (over the closed attitude loop):
                                 G(s) = K e^{-tau s} T_att(s) / (s (T2 s + 1))

where ``T_att`` is the attitude loop closed by its PD controller (see
``uavsim.lumped.lateral``). ``LumpedParams`` holds one point of that space,
validates it, and ``RANGES`` gives the paper's box for each loop.

    p = LumpedParams(loop="altitude", K=1.0, T_prop=0.1, T1=0.8, tau=0.02)
    p.check()   # raises UserError when a parameter is impossible
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from uavsim.errors import UserError

INNER_LOOPS = ("altitude", "roll", "pitch")
LATERAL_LOOPS = ("lateral_x", "lateral_y")
LOOPS = INNER_LOOPS + LATERAL_LOOPS

# Paper section III-C; altitude delay widened for vision (tau_in,alt up to 0.06 s).
RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "attitude": {"T_prop": (0.015, 0.3), "T1": (0.2, 2.0), "tau": (0.0005, 0.03)},
    "altitude": {"T_prop": (0.015, 0.3), "T1": (0.2, 2.0), "tau": (0.0005, 0.06)},
    "lateral": {"T2": (0.2, 6.0), "tau": (0.0005, 0.15)},
}

#: the parameters that place a process in its family's box (the gain K scales out)
BOX_KEYS: dict[str, tuple[str, ...]] = {"attitude": ("T_prop", "T1", "tau"), "altitude": ("T_prop", "T1", "tau"),
                                        "lateral": ("T2", "tau")}


def _log_box(family: str) -> tuple[np.ndarray, np.ndarray]:
    keys = BOX_KEYS[family]
    return np.log([RANGES[family][k][0] for k in keys]), np.log([RANGES[family][k][1] for k in keys])


def box_coordinates(family: str, values) -> np.ndarray:
    """Processes as (m, k) coordinates in [0, 1]: each of ``BOX_KEYS[family]`` of ``values`` (a mapping of
    (m,) arrays) on log scale over ``RANGES[family]``: where "nearest class" is measured."""
    lo, hi = _log_box(family)
    return (np.log(np.column_stack([np.asarray(values[k], dtype=float) for k in BOX_KEYS[family]])) - lo) / (hi - lo)


def from_box_coordinates(family: str, u: np.ndarray) -> dict[str, np.ndarray]:
    """``box_coordinates``'s inverse: (m, k) coordinates to ``BOX_KEYS[family]`` -> (m,) arrays."""
    lo, hi = _log_box(family)
    x = np.exp(lo + u * (hi - lo))
    return {k: x[:, d] for d, k in enumerate(BOX_KEYS[family])}


def nearest_centre(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Index (m,) of the nearest of ``centres`` (c, k) to each of ``points`` (m, k), box coordinates."""
    return np.argmin(((points[:, None, :] - centres[None, :, :]) ** 2).sum(axis=-1), axis=1)


def loop_family(loop: str) -> str:
    """Map a loop name to its parameter family: ``attitude``, ``altitude`` or ``lateral``."""
    if loop in ("roll", "pitch", "attitude"):
        return "attitude"
    if loop == "altitude":
        return "altitude"
    if loop in LATERAL_LOOPS or loop == "lateral":
        return "lateral"
    raise UserError(f"unknown loop {loop!r} (expected one of {', '.join(LOOPS)})")


@dataclass(frozen=True)
class LumpedParams:
    """One lumped process.

    Attributes
    ----------
    loop : str
        ``altitude``, ``roll``, ``pitch``, ``lateral_x`` or ``lateral_y``.
    K : float
        Loop gain, output units per command unit per second (type-1 loops).
    T_prop : float
        Propulsion time constant, s. For lateral loops: that of the attitude loop.
    T1 : float
        Body time constant, s. For lateral loops: that of the attitude loop.
    tau : float
        Total loop delay, s. For lateral loops: the outer delay tau_out.
    T2 : float or None
        Lateral drag time constant, s (lateral loops only).
    tau_in : float or None
        Attitude loop delay, s (lateral loops only).
    att_kp, att_kd : float or None
        Gains of the attitude PD that closes the inner loop (lateral loops only),
        for a unit-gain attitude process.
    att_filter_hz : float or None
        Cut-off of that PD's derivative filter, Hz (lateral loops only).
    """

    loop: str
    K: float
    T_prop: float
    T1: float
    tau: float
    T2: float | None = None
    tau_in: float | None = None
    att_kp: float | None = None
    att_kd: float | None = None
    att_filter_hz: float | None = None

    @property
    def family(self) -> str:
        return loop_family(self.loop)

    def check(self) -> LumpedParams:
        """Raise ``UserError`` naming the first impossible parameter; return self."""
        loop_family(self.loop)
        fields = {"K": self.K, "T_prop": self.T_prop, "T1": self.T1, "tau": self.tau}
        for name, v in fields.items():
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise UserError(f"{self.loop} model: {name} must be a finite number, got {v!r}")
        if self.K == 0:
            raise UserError(f"{self.loop} model: K must be non-zero")
        if self.T_prop <= 0 or self.T1 <= 0:
            raise UserError(f"{self.loop} model: time constants must be > 0 s (T_prop={self.T_prop}, T1={self.T1})")
        if self.tau < 0:
            raise UserError(f"{self.loop} model: delay tau must be >= 0 s, got {self.tau}")
        if self.family == "lateral":
            for name in ("T2", "tau_in", "att_kp", "att_kd", "att_filter_hz"):
                v = getattr(self, name)
                if v is None or not math.isfinite(v):
                    raise UserError(f"{self.loop} model: {name} is required for a lateral loop")
            if self.T2 <= 0 or self.tau_in < 0 or self.att_kp <= 0 or self.att_kd < 0:
                raise UserError(f"{self.loop} model: need T2 > 0, tau_in >= 0, att_kp > 0, att_kd >= 0")
        elif self.T2 is not None:
            raise UserError(f"{self.loop} model: T2 is only for lateral loops")
        return self

    def in_range(self, margin: float = 0.0) -> bool:
        """Whether the time parameters lie inside the paper's box (relative ``margin``)."""
        box = RANGES[self.family]
        vals = asdict(self)
        return all(lo * (1 - margin) <= vals[k] <= hi * (1 + margin) for k, (lo, hi) in box.items())

    def with_gain(self, K: float) -> LumpedParams:
        return replace(self, K=K)

    def as_dict(self) -> dict[str, float]:
        return {k: v for k, v in asdict(self).items() if v is not None and k != "loop"}
