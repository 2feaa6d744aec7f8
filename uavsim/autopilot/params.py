"""Identified PD gains as PX4 and ArduPilot parameters.

uavsim tunes a PD on the loop's output, in the session's units: with the error
``e = r - y`` (m or rad) and the command ``u`` in the session's command units,

    u = kp e - kd y'            (kp: command per output unit, kd: command s per output unit;
                                 the derivative through a first-order filter at derivative_filter_hz)

for a constant reference. Both autopilots close these loops as a cascade: a P
on the output gives a rate setpoint, a P on the rate gives the inner output
``a`` (PX4 and ArduPilot alike): ``a = K_rate (K_out e - y')``. That is the PD
``kp = K_rate K_out``, ``kd = K_rate`` in the autopilot's output units, so with
``S`` = autopilot output units per session command unit:

    K_out  = kp / kd            (1/s, whatever the units)
    K_rate = kd * S

=========  ===========================  =====================================  =========================
loop       PX4                          ArduPilot                              S: autopilot output per u
=========  ===========================  =====================================  =========================
altitude   MPC_Z_P = K_out              PSC_POSZ_P = K_out                     m/s^2 of vertical
           MPC_Z_VEL_P_ACC = K_rate     PSC_VELZ_P = K_rate                    acceleration per unit of u
           MPC_Z_VEL_D_ACC = 0          (cm and m cancel: both 1/s)            (--hover-thrust H: u is
                                                                               thrust 0..1, S = g / H)
roll       MC_ROLL_P = K_out            ATC_ANG_RLL_P = K_out                  normalized rate-controller
           MC_ROLLRATE_P = K_rate       ATC_RAT_RLL_P = K_rate                 output (torque, -1..1) per
           MC_ROLLRATE_D = 0            ATC_RAT_RLL_D = 0                      unit of u (1 for px4-roll
           MC_ROLLRATE_K = 1            ATC_RAT_RLL_FLTE = filter Hz           and ardupilot-roll imports)
pitch      MC_PITCH_P, MC_PITCHRATE_*   ATC_ANG_PIT_P, ATC_RAT_PIT_*           as roll
lateral_x  MPC_XY_P = K_out             PSC_POSXY_P = K_out                    m/s^2 of horizontal
lateral_y  MPC_XY_VEL_P_ACC = K_rate    PSC_VELXY_P = K_rate                   acceleration per unit of u
           MPC_XY_VEL_D_ACC = 0                                                (g = 9.80665 for u a tilt
                                                                               in rad)
=========  ===========================  =====================================  =========================

``S`` depends on the vehicle and on what the session's ``u`` was (a thrust, a
torque setpoint, an acceleration): the user gives it (``--cmd-scale S``, or
``--hover-thrust H`` for an altitude session whose u is normalized thrust) and
the export refuses without it. Integrators (``*_I``) and feed-forwards are not
written: the PD has none, and the autopilot's own stay as they are. The
derivative filter maps to ArduPilot's rate-error filter ``ATC_RAT_*_FLTE``;
PX4 filters the rate with the global ``IMU_GYRO_CUTOFF``, which is not written
(a comment gives the identified cut-off).

    from uavsim.autopilot import export_gains, write_params
    exp = export_gains(ans, "px4", cmd_scale=1.0)    # ans: uavsim identify's answer
    write_params(exp, "roll.params")
"""

from __future__ import annotations

import datetime as _dt
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uavsim.errors import UserError

__all__ = ["AUTOPILOTS", "G", "Param", "GainExport", "export_gains", "format_params", "write_params", "read_params",
           "MAPPING"]

AUTOPILOTS = ("px4", "ardupilot")
G = 9.80665  # m/s^2

#: loop -> autopilot -> (outer P, rate P, rate D or None, extra fixed params, derivative-filter param or None)
MAPPING: dict[str, dict[str, tuple[str, str, str | None, dict[str, float], str | None]]] = {
    "altitude": {"px4": ("MPC_Z_P", "MPC_Z_VEL_P_ACC", "MPC_Z_VEL_D_ACC", {}, None),
                 "ardupilot": ("PSC_POSZ_P", "PSC_VELZ_P", None, {}, None)},
    "roll": {"px4": ("MC_ROLL_P", "MC_ROLLRATE_P", "MC_ROLLRATE_D", {"MC_ROLLRATE_K": 1.0}, None),
             "ardupilot": ("ATC_ANG_RLL_P", "ATC_RAT_RLL_P", "ATC_RAT_RLL_D", {}, "ATC_RAT_RLL_FLTE")},
    "pitch": {"px4": ("MC_PITCH_P", "MC_PITCHRATE_P", "MC_PITCHRATE_D", {"MC_PITCHRATE_K": 1.0}, None),
              "ardupilot": ("ATC_ANG_PIT_P", "ATC_RAT_PIT_P", "ATC_RAT_PIT_D", {}, "ATC_RAT_PIT_FLTE")},
    "lateral_x": {"px4": ("MPC_XY_P", "MPC_XY_VEL_P_ACC", "MPC_XY_VEL_D_ACC", {}, None),
                  "ardupilot": ("PSC_POSXY_P", "PSC_VELXY_P", None, {}, None)},
    "lateral_y": {"px4": ("MPC_XY_P", "MPC_XY_VEL_P_ACC", "MPC_XY_VEL_D_ACC", {}, None),
                  "ardupilot": ("PSC_POSXY_P", "PSC_VELXY_P", None, {}, None)},
}

#: what S means for each loop (the unit of the rate gain is that over the output's rate unit)
_S_UNIT = {"altitude": "m/s^2 per command unit", "roll": "normalized torque per command unit",
           "pitch": "normalized torque per command unit", "lateral_x": "m/s^2 per command unit",
           "lateral_y": "m/s^2 per command unit"}
_RATE_UNIT = {"altitude": ("(m/s^2)/(m/s)", "1/s"), "roll": ("norm. torque/(rad/s)", "1/(rad/s)"),
              "pitch": ("norm. torque/(rad/s)", "1/(rad/s)"), "lateral_x": ("(m/s^2)/(m/s)", "1/s"),
              "lateral_y": ("(m/s^2)/(m/s)", "1/s")}
_OUT_UNIT = {"altitude": "(m/s)/m = 1/s", "roll": "(rad/s)/rad = 1/s", "pitch": "(rad/s)/rad = 1/s",
             "lateral_x": "(m/s)/m = 1/s", "lateral_y": "(m/s)/m = 1/s"}


@dataclass(frozen=True)
class Param:
    """One autopilot parameter: name, value, unit and how it was computed."""

    name: str
    value: float
    unit: str
    why: str


@dataclass
class GainExport:
    """Parameters for one loop on one autopilot, and the mapping that produced them."""

    autopilot: str
    loop: str
    params: list[Param]
    cmd_scale: float
    cmd_scale_source: str
    source: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, float]:
        return {p.name: p.value for p in self.params}


def _finite_positive(x: Any, what: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise UserError(f"{what} must be a number, got {x!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise UserError(f"{what} must be > 0 and finite, got {v!r}")
    return v


def export_gains(ans: dict[str, Any], autopilot: str, *, cmd_scale: float | None = None,
                 hover_thrust: float | None = None, gains_key: str = "gains") -> GainExport:
    """Map an identification answer's PD gains onto ``autopilot``'s parameters (module docstring).

    Parameters
    ----------
    ans : dict
        ``uavsim identify --json``'s answer (``loop``, ``gains`` with ``kp``, ``kd``,
        ``derivative_filter_hz``; ``class``, ``params`` are quoted in the comments).
    autopilot : ``"px4"`` or ``"ardupilot"``
    cmd_scale : float
        ``S``, the autopilot's inner output units per session command unit (``_S_UNIT``).
    hover_thrust : float
        Altitude only, instead of ``cmd_scale``: u is normalized thrust and ``S = g / hover_thrust``.
    gains_key : which gains of the answer (``gains``, ``gains_table``, ``gains_optimum``, ``gains_measured_point``)

    Raises
    ------
    UserError
        Unknown autopilot or loop, no scale, gains that a P-P cascade cannot take (kp or kd <= 0).
    """
    if autopilot not in AUTOPILOTS:
        raise UserError(f"unknown autopilot {autopilot!r} (known: {', '.join(AUTOPILOTS)})")
    loop = ans.get("loop")
    if loop not in MAPPING:
        raise UserError(f"cannot map the {loop!r} loop onto {autopilot} parameters (mapped: {', '.join(MAPPING)})")
    g = ans.get(gains_key)
    if not isinstance(g, dict) or "kp" not in g or "kd" not in g:
        raise UserError(f"the identification answer has no {gains_key} (kp, kd) to export")
    kp = float(g["kp"])
    kd = float(g["kd"])
    if not (math.isfinite(kp) and math.isfinite(kd) and kp > 0 and kd > 0):
        raise UserError(f"cannot map kp = {kp:.6g}, kd = {kd:.6g} onto a P-P cascade (both must be > 0: the "
                        f"outer P is kp/kd and the rate P is kd)")
    if cmd_scale is not None and hover_thrust is not None:
        raise UserError("give --cmd-scale or --hover-thrust, not both")
    if hover_thrust is not None:
        if loop != "altitude":
            raise UserError(f"--hover-thrust is for the altitude loop (u a normalized thrust), not {loop}; "
                            "give --cmd-scale")
        H = _finite_positive(hover_thrust, "--hover-thrust")
        if H >= 1:
            raise UserError(f"--hover-thrust is the normalized hover thrust, in (0, 1), got {H:g}")
        S, S_src = G / H, f"S = g / hover thrust = {G} / {H:g} m/s^2 per unit of normalized thrust"
    elif cmd_scale is not None:
        S = _finite_positive(cmd_scale, "--cmd-scale")
        S_src = f"S = {S:g} {_S_UNIT[loop]} (given)"
    else:
        how = "--hover-thrust H (u normalized thrust) or --cmd-scale S" if loop == "altitude" else "--cmd-scale S"
        raise UserError(f"the {loop} gains need the vehicle's scale from the session's command units: {how} "
                        f"({_S_UNIT[loop]})")
    outer, rate, rate_d, fixed, filt = MAPPING[loop][autopilot]
    rate_unit = _RATE_UNIT[loop][0]
    params = [
        Param(outer, kp / kd, _OUT_UNIT[loop], f"kp / kd = {kp:.6g} / {kd:.6g}"),
        Param(rate, kd * S, rate_unit, f"kd * S = {kd:.6g} * {S:.6g}"),
    ]
    if rate_d is not None:
        params.append(Param(rate_d, 0.0, "", "the PD has no derivative on the rate"))
    params += [Param(k, v, "", "rate gain multiplier: the rate P above is the whole gain") for k, v in fixed.items()]
    notes = []
    fhz = g.get("derivative_filter_hz")
    if filt is not None and fhz is not None and math.isfinite(float(fhz)) and float(fhz) > 0:
        params.append(Param(filt, float(fhz), "Hz", "the PD's derivative filter, on the rate error"))
    elif fhz is not None:
        notes.append(f"derivative filter of the PD: {float(fhz):.4g} Hz"
                     + (" (PX4 filters the rate with IMU_GYRO_CUTOFF, global: not written)" if autopilot == "px4"
                        else ""))
    notes.append("integrators and feed-forwards are not written: the PD has none; the autopilot's stay as set")
    if loop == "altitude":
        notes.append("the acceleration (thrust) loop below is assumed to deliver the acceleration setpoint: S is "
                     "its m/s^2 per unit of the session's u")
    src = {k: ans[k] for k in ("loop", "class", "params", "run", "model_dir") if k in ans}
    src["gains"] = {k: g[k] for k in ("kp", "kd", "derivative_filter_hz") if k in g}
    src["gains_key"] = gains_key
    return GainExport(autopilot, loop, params, S, S_src, src, notes)


def _header(exp: GainExport, comment: str) -> list[str]:
    s = exp.source
    lines = [
        f"uavsim {exp.autopilot} parameters for the {exp.loop} loop, written "
        f"{_dt.datetime.now(_dt.UTC).strftime('%Y-%m-%d %H:%M UTC')}",
        f"identified: class {s.get('class')}, model {s.get('params')}",
        f"PD in session units ({s.get('gains_key')}): kp = {s['gains'].get('kp'):.6g} command/output unit, "
        f"kd = {s['gains'].get('kd'):.6g} command s/output unit",
        "mapping: u = kp e - kd y'  ==  rate P * (outer P * e - y'), so outer P = kp / kd, rate P = kd * S",
        f"unit of the session's command u -> autopilot: {exp.cmd_scale_source}",
        *exp.notes,
        "parameters (name, value; unit and formula in the comment above each):",
    ]
    return [f"{comment} {ln}" for ln in lines]


def format_params(exp: GainExport) -> str:
    """The file text: QGroundControl ``.params`` (PX4) or Mission Planner ``.parm`` (ArduPilot)."""
    out = _header(exp, "#")
    for p in exp.params:
        out.append(f"# {p.name}: {p.unit + ', ' if p.unit else ''}{p.why}")
        if exp.autopilot == "px4":
            # vehicle id, component id, name, value, MAV_PARAM_TYPE (9 = REAL32)
            out.append(f"1\t1\t{p.name}\t{p.value:.9g}\t9")
        else:
            out.append(f"{p.name},{p.value:.9g}")
    return "\n".join(out) + "\n"


def write_params(exp: GainExport, path: str | os.PathLike) -> Path:
    """Write ``format_params(exp)`` to ``path`` (atomically)."""
    import tempfile

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=p.parent, prefix=p.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(format_params(exp))
        os.replace(tmp, p)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return p


def read_params(path: str | os.PathLike) -> dict[str, float]:
    """Parameter values of a ``.params`` (QGC, tab-separated) or ``.parm`` (``NAME,VALUE``) file."""
    out: dict[str, float] = {}
    for ln in Path(path).read_text().splitlines():
        ln = ln.strip()
        if not ln or ln.startswith("#"):
            continue
        if "\t" in ln:
            parts = ln.split("\t")
            out[parts[2]] = float(parts[3])
        else:
            name, value = ln.replace(" ", ",").split(",", 1)
            out[name] = float(value)
    return out
