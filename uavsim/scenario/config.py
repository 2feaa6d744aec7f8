"""Scenario files (``scenarios/*.toml``, format ``uavsim-scenario/1``), read strictly.

A scenario names the vehicle's true loops, the sensor chain and the test; the
flow (``uavsim.scenario.flow``) identifies and tunes the loops through that
chain and runs the test. Unknown keys, wrong types and impossible values are
``UserError``s naming the file and key.

    format = "uavsim-scenario/1"
    description = "normal camera, Kalman filter (PBVS)"
    seed = 7
    loops = ["altitude"]            # altitude, lateral_y (cascaded over roll)
    estimator = "kf"                # kf (PBVS) | camera (IBVS)

    [camera]                        # a preset and any CameraParams overrides
    preset = "normal"
    distance_m = 4.0

    [identification]                # NP-MRFT and the identifier
    beta = -0.73
    method = "auto"                 # dnn | mrft-df | auto (dnn when its networks exist)

    [test]
    kind = "step"                   # step | wind | pull | target-step
    size_m = 1.0

    [truth.altitude]                # the vehicle's true lumped loop
    K = 40.0
    T_prop = 0.08
    T1 = 0.6
    tau = 0.008

    scn = load_scenario("scenarios/normal-camera-kf.toml")
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams
from uavsim.vision.camera import CameraParams, camera_preset
from uavsim.vision.imu import ImuParams
from uavsim.vision.schedules import SwitchParams

__all__ = ["FORMAT", "Scenario", "Identification", "TestSpec", "load_scenario", "parse_scenario", "DEFAULT_TRUTH"]

FORMAT = "uavsim-scenario/1"
LOOPS = ("altitude", "lateral_y")
ESTIMATORS = ("kf", "camera")
METHODS = ("dnn", "mrft-df", "auto")
TEST_KINDS = ("step", "wind", "pull", "target-step", "none")

#: the vehicle's true loops when a scenario does not say (paper's hexarotor class)
DEFAULT_TRUTH: dict[str, dict[str, float]] = {
    "altitude": {"K": 40.0, "T_prop": 0.08, "T1": 0.6, "tau": 0.008},
    # roll loop of the vehicle (IMU-measured) that the lateral loop cascades over
    "roll": {"K": 20.0, "T_prop": 0.06, "T1": 0.5, "tau": 0.01},
    # lateral: K of the outer loop and the drag time constant T2, outer delay tau
    "lateral_y": {"K": 2.0, "T2": 2.0, "tau": 0.005},
}


@dataclass(frozen=True)
class Identification:
    """NP-MRFT test and identifier settings.

    Attributes
    ----------
    beta : float
        MRFT parameter of the altitude and roll tests.
    beta_lateral : float
        MRFT parameter of the lateral test.
    h_altitude, h_roll, h_lateral : float
        Relay amplitudes, command units.
    hover_s : float
        Hover segment for the noise estimate, s.
    duration_s : float
        Relay test length, s.
    method : str
        ``dnn`` (trained networks, ``uavsim.learning``), ``mrft-df`` (the
        describing-function MRFT rule on the measured cycle; no model), ``auto``.
    model_dir : str
        Networks folder for ``dnn`` ('' = the default).
    pm_deg : float
        Phase margin of the tuning rule, deg.
    """

    beta: float = -0.73
    beta_lateral: float = -0.6
    h_altitude: float = 0.1
    h_roll: float = 0.05
    h_lateral: float = 0.5
    hover_s: float = 5.0
    duration_s: float = 20.0
    method: str = "auto"
    model_dir: str = ""
    pm_deg: float = 20.0


@dataclass(frozen=True)
class TestSpec:
    """The test after tuning.

    Attributes
    ----------
    kind : str
        ``step`` (reference step), ``wind``, ``pull``, ``target-step`` (the target
        moves; schedules switch), ``none``.
    loop : str
        Loop the test acts on ('' = the first of ``loops``).
    duration_s : float
        Test length, s.
    size_m : float
        Step size (reference or target), m.
    time_s : float
        Step / wind-on time, s.
    speed_mps, direction_deg, gust_std_mps : float
        Wind.
    force_N, t_release_s : float
        Pull force and release time (the pull starts at ``time_s``).
    axis : str
        Pull axis x, y, z ('' = the loop's axis).
    """

    kind: str = "step"
    loop: str = ""
    duration_s: float = 10.0
    size_m: float = 1.0
    time_s: float = 1.0
    speed_mps: float = 5.0
    direction_deg: float = 90.0
    gust_std_mps: float = 0.0
    force_N: float = 10.0
    t_release_s: float = 6.0
    axis: str = ""


@dataclass
class Scenario:
    """A parsed scenario file (see the module docstring).

    ``truth`` holds the vehicle's true ``altitude`` and ``roll`` loops;
    ``lateral_truth`` the outer lateral numbers ``K``, ``T2`` (s), ``tau`` (s),
    completed by the flow with the roll loop and its tuned PD.
    """

    name: str
    description: str
    seed: int
    loops: tuple[str, ...]
    estimator: str
    camera: CameraParams
    imu: ImuParams
    identification: Identification
    test: TestSpec
    truth: dict[str, LumpedParams]
    lateral_truth: dict[str, float]
    switch: SwitchParams = field(default_factory=SwitchParams)
    path: Path | None = None

    @property
    def test_loop(self) -> str:
        return self.test.loop or self.loops[0]


def _err(where: str, msg: str) -> UserError:
    return UserError(f"{where}: {msg}")


def _table(doc: dict, key: str, where: str) -> dict:
    v = doc.get(key, {})
    if not isinstance(v, dict):
        raise _err(where, f"[{key}] must be a table")
    return v


def _fill(cls, table: dict, where: str, skip: tuple[str, ...] = ()) -> Any:
    """Build dataclass ``cls`` from ``table``, rejecting unknown keys and wrong types."""
    known = {f.name: f for f in fields(cls) if f.name not in skip}
    kw = {}
    for k, v in table.items():
        if k not in known:
            raise _err(where, f"unknown key {k!r} (known: {', '.join(sorted(known))})")
        default = getattr(cls(), k) if not skip else None
        kw[k] = _typed(v, default, f"{where}.{k}")
    return cls(**kw)


def _typed(v: Any, default: Any, where: str) -> Any:
    if isinstance(default, bool):
        if not isinstance(v, bool):
            raise _err(where, f"must be true or false, got {v!r}")
        return v
    if isinstance(default, (int, float)) and not isinstance(default, bool):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise _err(where, f"must be a finite number, got {v!r}")
        return type(default)(v) if isinstance(default, float) else v
    if isinstance(default, str):
        if not isinstance(v, str):
            raise _err(where, f"must be a string, got {v!r}")
        return v
    return v


def _check_ident(ident: Identification, where: str) -> None:
    for k in ("beta", "beta_lateral"):
        b = getattr(ident, k)
        if not -1 < b < 0:
            raise _err(where, f"identification.{k} must be in (-1, 0), got {b}")
    for k in ("h_altitude", "h_roll", "h_lateral", "hover_s", "duration_s", "pm_deg"):
        if getattr(ident, k) <= 0:
            raise _err(where, f"identification.{k} must be > 0")
    if ident.method not in METHODS:
        raise _err(where, f"identification.method must be one of {', '.join(METHODS)}, got {ident.method!r}")


def _check_test(test: TestSpec, loops: tuple[str, ...], where: str) -> None:
    if test.kind not in TEST_KINDS:
        raise _err(where, f"test.kind must be one of {', '.join(TEST_KINDS)}, got {test.kind!r}")
    if test.loop and test.loop not in loops:
        raise _err(where, f"test.loop {test.loop!r} is not among loops {list(loops)}")
    if test.duration_s <= 0 or test.time_s < 0 or test.time_s >= test.duration_s:
        raise _err(where, "test needs duration_s > 0 and 0 <= time_s < duration_s")
    if test.kind == "pull" and not test.time_s < test.t_release_s < test.duration_s:
        raise _err(where, "pull test needs time_s < t_release_s < duration_s")
    if test.axis not in ("", "x", "y", "z"):
        raise _err(where, f"test.axis must be x, y or z, got {test.axis!r}")
    if test.kind == "wind" and (loops[0] if not test.loop else test.loop) == "altitude" and test.axis != "z":
        raise _err(where, "wind blows horizontally: a wind test needs the lateral_y loop")


def _truth(doc: dict, loops: tuple[str, ...], where: str) -> tuple[dict[str, LumpedParams], dict[str, float]]:
    t = _table(doc, "truth", where)
    bad = sorted(set(t) - {"altitude", "roll", "lateral_y"})
    if bad:
        raise _err(where, f"unknown [truth] table(s) {bad} (known: altitude, roll, lateral_y)")
    out: dict[str, LumpedParams] = {}
    for loop in ("altitude", "roll", "lateral_y"):
        vals = dict(DEFAULT_TRUTH[loop])
        given = t.get(loop, {})
        if not isinstance(given, dict):
            raise _err(where, f"[truth.{loop}] must be a table")
        for k, v in given.items():
            if k not in vals:
                raise _err(where, f"[truth.{loop}]: unknown key {k!r} (known: {', '.join(sorted(vals))})")
            vals[k] = _typed(v, 0.0, f"truth.{loop}.{k}")
        if loop == "lateral_y":
            continue  # built by the flow over the tuned roll loop
        try:
            out[loop] = LumpedParams(loop, **vals).check()
        except UserError as exc:
            raise _err(where, str(exc)) from None
    lat = dict(DEFAULT_TRUTH["lateral_y"])
    lat.update({k: float(v) for k, v in t.get("lateral_y", {}).items()})
    for k, v in lat.items():
        if not v > 0:
            raise _err(where, f"truth.lateral_y.{k} must be > 0")
    return out, lat


_TOP = ("format", "description", "seed", "loops", "estimator", "camera", "imu", "identification", "test", "truth",
        "switch")


def parse_scenario(doc: dict, name: str = "scenario", where: str = "scenario") -> Scenario:
    """Build a ``Scenario`` from a parsed TOML document (strict: ``uavsim.schema.scenario`` first)."""
    from uavsim.schema import validate

    validate("scenario", doc, where)
    bad = sorted(set(doc) - set(_TOP))
    if bad:
        raise _err(where, f"unknown key(s) {bad} (known: {', '.join(_TOP)})")
    if doc.get("format") != FORMAT:
        raise _err(where, f"format must be {FORMAT!r}, got {doc.get('format')!r}")
    desc = doc.get("description", "")
    if not isinstance(desc, str):
        raise _err(where, "description must be a string")
    seed = doc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise _err(where, f"seed must be an integer >= 0, got {seed!r}")
    loops = doc.get("loops", ["altitude"])
    if not isinstance(loops, list) or not loops or any(lp not in LOOPS for lp in loops) or len(set(loops)) != len(loops):
        raise _err(where, f"loops must be a non-empty list of distinct names from {list(LOOPS)}, got {loops!r}")
    est = doc.get("estimator", "kf")
    if est not in ESTIMATORS:
        raise _err(where, f"estimator must be one of {', '.join(ESTIMATORS)}, got {est!r}")
    cam_t = dict(_table(doc, "camera", where))
    preset = cam_t.pop("preset", "normal")
    if not isinstance(preset, str):
        raise _err(where, "camera.preset must be a string")
    for k, v in cam_t.items():
        if k in CameraParams.__dataclass_fields__ and k != "name":
            cam_t[k] = _typed(v, getattr(CameraParams(), k), f"camera.{k}")
    try:
        camera = camera_preset(preset, **cam_t)
    except UserError as exc:
        raise _err(where, str(exc)) from None
    imu = _fill(ImuParams, _table(doc, "imu", where), f"{where}: imu")
    ident = _fill(Identification, _table(doc, "identification", where), f"{where}: identification")
    _check_ident(ident, where)
    test = _fill(TestSpec, _table(doc, "test", where), f"{where}: test")
    _check_test(test, tuple(loops), where)
    switch = _fill(SwitchParams, _table(doc, "switch", where), f"{where}: switch")
    try:
        imu.check()
        switch.check()
    except UserError as exc:
        raise _err(where, str(exc)) from None
    truth, lateral = _truth(doc, tuple(loops), where)
    return Scenario(name, desc, seed, tuple(loops), est, camera, imu, ident, test, truth, lateral, switch)


def load_scenario(path: str | Path) -> Scenario:
    """Read and check a scenario file; ``UserError`` names the file on any problem."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: no such scenario file")
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: not valid TOML ({exc})") from None
    scn = parse_scenario(doc, name=p.stem, where=str(p))
    scn.path = p
    return scn
