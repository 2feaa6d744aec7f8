"""The simulated hexarotor in 3D: body pose and rotor thrust arrows over time.

A replay of a simulated episode (``LoopBatch(record_state=True)`` or a
scenario episode) holds the vehicle's six joint positions ``qpos`` (x, y, z in
m; roll, pitch, yaw in rad) and the six rotor thrusts (N) at the control rate.
This module turns them into Rerun entities under ``<base>/world``:

* ``vehicle``: ``Transform3D`` over time (translation and the quaternion of the
  joint chain roll -> pitch -> yaw, the order of the MJCF hinges);
* ``vehicle/body``, ``vehicle/arms``, ``vehicle/rotors``: static geometry read
  from the vehicle's MJCF model (box, arm capsules, rotor discs at the rotor
  sites);
* ``vehicle/thrust``: ``Arrows3D`` over time, one arrow per rotor from its site
  along the body z axis, ``THRUST_ARROW_M`` metres per hover thrust;
* ``path``: the static 3D path of the body origin.

    from uavsim.viz.vehicle3d import log_vehicle
    log_vehicle(rec, "runs/relay", t, res.qpos[0], res.rotor_force[0])
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from uavsim.model.vehicle import Vehicle, hexarotor_mjcf

#: arrow length of a rotor at hover thrust, m
THRUST_ARROW_M = 0.3


@dataclass(frozen=True)
class Geometry:
    """The hexarotor's drawable parts in the body frame (m).

    Attributes
    ----------
    box_half : (3,) half extents of the central box
    rotor_pos : (6, 3) rotor sites (where the thrust acts)
    prop_radius : propeller disc radius
    hover_thrust : hover thrust per rotor, N
    """

    box_half: np.ndarray
    rotor_pos: np.ndarray
    prop_radius: float
    hover_thrust: float


@lru_cache(maxsize=4)
def geometry(vehicle: Vehicle | None = None) -> Geometry:
    """Read the body box, rotor sites and disc radius from the vehicle's MJCF model."""
    import mujoco

    v = (vehicle or Vehicle()).check()
    m = mujoco.MjModel.from_xml_string(hexarotor_mjcf(v))
    sites = np.array([m.site(f"rotor{i}").pos for i in range(v.n_rotors)], dtype=np.float64)
    box = next(m.geom_size[g] for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX)
    cyl = [m.geom_size[g][0] for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CYLINDER]
    return Geometry(np.array(box, dtype=np.float64), sites, float(cyl[0]) if cyl else v.prop_radius_m,
                    v.hover_thrust_per_rotor_N)


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (T, 4) quaternions stored (w, x, y, z)."""
    w1, x1, y1, z1 = a.T
    w2, x2, y2, z2 = b.T
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=1)


def body_quaternion(qpos: np.ndarray) -> np.ndarray:
    """Body orientation of joint positions, (T, 4) quaternions (x, y, z, w), Rerun's order.

    Parameters
    ----------
    qpos : (T, 6)
        x, y, z (m), roll, pitch, yaw (rad); the hinges are nested in that
        order, so ``R = Rx(roll) Ry(pitch) Rz(yaw)`` (what MuJoCo computes).
    """
    q = np.asarray(qpos, dtype=np.float64)
    half = 0.5 * q[:, 3:6]
    c, s = np.cos(half), np.sin(half)
    z = np.zeros(len(q))
    qx = np.stack([c[:, 0], s[:, 0], z, z], axis=1)
    qy = np.stack([c[:, 1], z, s[:, 1], z], axis=1)
    qz = np.stack([c[:, 2], z, z, s[:, 2]], axis=1)
    wxyz = _qmul(_qmul(qx, qy), qz)
    return wxyz[:, [1, 2, 3, 0]]


def log_vehicle(rec: Any, base: str, t: np.ndarray, qpos: np.ndarray, rotor_force: np.ndarray | None,
                vehicle: Vehicle | None = None, timeline: str = "time") -> dict[str, int]:
    """Log the vehicle's pose and thrust arrows under ``<base>/world``.

    Parameters
    ----------
    rec : rerun.RecordingStream
    base : str
        Entity path of the run (``runs/<stem>``).
    t : (T,) s
        Control-rate times.
    qpos : (T, 6)
        Joint positions (m, rad); non-finite rows (a diverged episode) are skipped.
    rotor_force : (T, 6) N or None
        Rotor thrusts; None logs no arrows.
    vehicle : Vehicle
        The airframe (default: the paper's hexarotor).
    timeline : str
        Name of the duration timeline.

    Returns
    -------
    dict
        Rows logged per temporal entity path (static geometry not counted).
    """
    import rerun as rr

    g = geometry(vehicle)
    w = f"{base}/world"
    t = np.asarray(t, dtype=np.float64)
    q = np.asarray(qpos, dtype=np.float64)
    ok = np.isfinite(q).all(axis=1)
    rows: dict[str, int] = {}
    rec.log(w, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    veh = f"{w}/vehicle"
    rec.log(f"{veh}/body", rr.Boxes3D(half_sizes=[g.box_half], colors=[[38, 89, 178]], fill_mode="solid"),
            static=True)
    rp = g.rotor_pos
    arms = [[[0.0, 0.0, 0.0], [x, y, 0.0]] for x, y, _ in rp]
    rec.log(f"{veh}/arms", rr.LineStrips3D(arms, radii=0.012, colors=[[50, 50, 50]]), static=True)
    colors = [[217, 77, 51] if i in (0, len(rp) - 1) else [77, 77, 89] for i in range(len(rp))]
    rec.log(f"{veh}/rotors", rr.Cylinders3D(lengths=[0.008] * len(rp), radii=[g.prop_radius] * len(rp),
                                            centers=rp, colors=colors), static=True)
    if ok.any():
        rec.send_columns(veh, indexes=[rr.TimeColumn(timeline, duration=t[ok])],
                         columns=rr.Transform3D.columns(translation=q[ok, :3], quaternion=body_quaternion(q[ok])))
        rows[veh] = int(ok.sum())
        rec.log(f"{w}/path", rr.LineStrips3D([q[ok, :3]], radii=0.004, colors=[[31, 119, 180]]), static=True)
    if rotor_force is not None:
        f = np.asarray(rotor_force, dtype=np.float64)
        okf = ok & np.isfinite(f).all(axis=1)
        if okf.any():
            m, n = int(okf.sum()), rp.shape[0]
            vec = np.zeros((m, n, 3))
            vec[:, :, 2] = f[okf] * (THRUST_ARROW_M / g.hover_thrust)
            cols = rr.Arrows3D.columns(vectors=vec.reshape(-1, 3), origins=np.tile(rp, (m, 1)))
            rec.log(f"{veh}/thrust", rr.Arrows3D.from_fields(colors=[[255, 140, 0]], radii=0.008), static=True)
            rec.send_columns(f"{veh}/thrust", indexes=[rr.TimeColumn(timeline, duration=t[okf])],
                             columns=cols.partition([n] * m))
            rows[f"{veh}/thrust"] = m
    return rows
