"""Draw docs/replay.png: a replayed limit cycle, read back from the Rerun recording.

``uavsim replay`` writes the recording (by default a noisy NP-MRFT episode of
the demo's training set, ``datasets/small.h5`` class 1 episode 5, simulated
again exactly); this script then reads the ``.rrd`` back with Rerun's own
reader (``rerun.chunk.RrdReader``) and draws what it holds with matplotlib,
because the Rerun viewer cannot open a window on a headless machine (the
viewer's own screenshot is ``uavsim.viz.viewer_png``): y as the
relay saw it beside the noise-free y_true, e with the switches, accepted
extrema and tau_obs windows, u, the phase portraits, and the vehicle's pose
with its rotor thrust arrows at the highest point of the cycle.

    python -m uavsim.viz.replay_png                                  # datasets/small.h5 -> docs/replay.png
    python -m uavsim.viz.replay_png datasets/small.h5 docs/replay.png --class 1 --episode 5
    python -m uavsim.viz.replay_png --rrd out/demo-altitude.rrd out/x.png   # an existing recording
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import matplotlib
import numpy as np

from uavsim.errors import UserError

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read_back(rrd: str | Path) -> dict[str, dict[str, list]]:
    """Every chunk of a recording: entity -> {column -> row values}, chunks concatenated, ``time`` in s."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(rrd).store().stream():
        rb = chunk.to_record_batch()
        ent = rb.schema.metadata[b"rerun:entity_path"].decode()
        cols = out.setdefault(ent, {})
        for name in rb.schema.names:
            if name.startswith("rerun.controls"):
                continue
            col = rb.column(name)
            if name == "time":
                vals = list(col.cast(pa.int64()).to_numpy() * 1e-9)
            else:
                vals = col.to_pylist()
            cols.setdefault(name, []).extend(vals)
    return out


def _series(data: dict, ent: str) -> tuple[np.ndarray, np.ndarray]:
    c = data.get(ent)
    if not c or "time" not in c:
        return np.zeros(0), np.zeros(0)
    return np.asarray(c["time"], float), np.array([v[0] for v in c["Scalars:scalars"]], float)


def _draw_vehicle(ax, data: dict, base: str, t_at: float) -> None:
    veh = data.get(f"{base}/world/vehicle")
    if not veh:
        ax.text2D(0.5, 0.5, "no vehicle pose\n(not a simulation)", ha="center", va="center", transform=ax.transAxes)
        return
    from scipy.spatial.transform import Rotation

    tv = np.asarray(veh["time"], float)
    k = int(np.argmin(np.abs(tv - t_at)))
    pos = np.asarray(veh["Transform3D:translation"][k][0], float)
    R = Rotation.from_quat(np.asarray(veh["Transform3D:quaternion"][k][0], float)).as_matrix()  # x, y, z, w

    def world(p):
        return (R @ np.asarray(p, float).T).T + pos

    rot = data[f"{base}/world/vehicle/rotors"]
    centers = np.asarray(rot["Cylinders3D:centers"][0], float)
    radius = float(rot["Cylinders3D:radii"][0][0])
    half = np.asarray(data[f"{base}/world/vehicle/body"]["Boxes3D:half_sizes"][0][0], float)
    for c in centers:  # arms and rotor discs
        a = world([[0, 0, 0], [c[0], c[1], 0]])
        ax.plot(a[:, 0], a[:, 1], a[:, 2], color="0.25", lw=2)
        ang = np.linspace(0, 2 * np.pi, 40)
        disc = world(np.column_stack([c[0] + radius * np.cos(ang), c[1] + radius * np.sin(ang), np.full(40, c[2])]))
        ax.plot(disc[:, 0], disc[:, 1], disc[:, 2], color="0.5", lw=0.8)
    sx, sy, sz = half
    corners = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
    for i in range(8):
        for j in range(i + 1, 8):
            if np.count_nonzero(corners[i] != corners[j]) == 1:
                e = world(corners[[i, j]])
                ax.plot(e[:, 0], e[:, 1], e[:, 2], color="C0", lw=1.2)
    thr = data.get(f"{base}/world/vehicle/thrust")
    if thr and "time" in thr:
        kt = int(np.argmin(np.abs(np.asarray(thr["time"], float) - t_at)))
        o = world(np.asarray(thr["Arrows3D:origins"][kt], float))
        v = (R @ np.asarray(thr["Arrows3D:vectors"][kt], float).T).T
        ax.quiver(o[:, 0], o[:, 1], o[:, 2], v[:, 0], v[:, 1], v[:, 2], color="C1", arrow_length_ratio=0.15)
    path = data.get(f"{base}/world/path")
    if path:
        p = np.asarray(path["LineStrips3D:strips"][0][0], float)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color="C0", lw=0.6, alpha=0.6)
    ax.set_xlim(-0.6, 0.6)
    ax.set_ylim(-0.6, 0.6)
    ax.set_zlim(pos[2] - 0.3, pos[2] + 0.5)
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7)
    ax.set_zlabel("z (m)", fontsize=7)
    ax.tick_params(labelsize=6)
    ax.set_title(f"vehicle at t = {tv[k]:.2f} s, z = {1000 * pos[2]:+.1f} mm\n(thrust arrows: 0.3 m per hover thrust)",
                 fontsize=8)


def draw(rrd: str | Path, out: str | Path, title: str = "") -> None:
    """Draw ``out`` from the replay recording ``rrd`` (its first run)."""
    data = read_back(rrd)
    bases = sorted({e.split("/")[2] for e in data if e.startswith("/runs/")})
    base = f"/runs/{bases[0]}"
    t, y = _series(data, f"{base}/y")
    tt, yt = _series(data, f"{base}/y_true")
    _, e = _series(data, f"{base}/e")
    tu, u = _series(data, f"{base}/u")
    ts, es = _series(data, f"{base}/switches")
    tx, ex = _series(data, f"{base}/extrema")
    ti, inh = _series(data, f"{base}/inhibition")
    lo = max(t[0], t[-1] - 3.0)  # the last seconds: the settled cycle
    m = t >= lo

    fig = plt.figure(figsize=(11, 7.2))
    gs = fig.add_gridspec(3, 2, width_ratios=[1.7, 1], height_ratios=[1.2, 1.2, 0.8])
    a0 = fig.add_subplot(gs[0, 0])
    if tt.size:
        a0.plot(tt[tt >= lo], yt[tt >= lo], lw=2.2, color="C9", alpha=0.8, label="y_true (noise-free)")
    a0.plot(t[m], y[m], lw=0.8, color="C0", label="y (as the relay saw it)")
    a0.set_ylabel("y (m)")
    a0.legend(loc="upper right", fontsize=7)
    a1 = fig.add_subplot(gs[1, 0], sharex=a0)
    a1.plot(t[m], e[m], lw=0.9, color="C2", label="e = r - y")
    if ti.size:
        on = inh > 0.5
        edges = np.flatnonzero(np.diff(on.astype(int)))
        starts = [ti[0]] if on[0] else []
        starts += [ti[i + 1] for i in edges if on[i + 1]]
        ends = [ti[i + 1] for i in edges if not on[i + 1]] + ([ti[-1]] if on[-1] else [])
        for a, b in zip(starts, ends, strict=False):
            if b >= lo:
                a1.axvspan(max(a, lo), b, color="0.85", lw=0)
    ms, mx = ts >= lo, tx >= lo
    a1.plot(ts[ms], es[ms], "v", color="C3", ms=5, label="switch")
    a1.plot(tx[mx], ex[mx], "o", mfc="none", color="C1", ms=6, label="accepted extremum")
    a1.set_ylabel("e (m)")
    a1.legend(loc="upper right", fontsize=7)
    a1.set_title("grey: tau_obs inhibition windows", fontsize=8)
    a2 = fig.add_subplot(gs[2, 0], sharex=a0)
    a2.step(tu[tu >= lo], u[tu >= lo], where="post", color="C3")
    a2.set_ylabel("u")
    a2.set_xlabel("t (s)")

    a3 = fig.add_subplot(gs[0, 1])
    ph = data.get(f"{base}/phase")
    if ph:
        p = np.asarray(ph["LineStrips2D:strips"][0][0], float)
        a3.plot(p[:, 0], p[:, 1], lw=0.5, color="C2", alpha=0.5, label="measured e")
    pt = data.get(f"{base}/phase/noise_free")
    if pt:
        p = np.asarray(pt["LineStrips2D:strips"][0][0], float)
        k = p.shape[0] // 3  # the settled part
        a3.plot(p[k:, 0], p[k:, 1], lw=1.2, color="C9", label="noise-free e")
    a3.set_xlabel("e (m)")
    a3.set_ylabel("de/dt (m/s)")
    a3.legend(loc="upper right", fontsize=7)
    a3.set_title("phase portrait", fontsize=8)
    a4 = fig.add_subplot(gs[1:, 1], projection="3d")
    t_top = float(tt[np.argmax(np.where(tt >= lo, yt, -np.inf))]) if tt.size else float(t[-1])
    _draw_vehicle(a4, data, base, t_top)
    fig.suptitle(title or f"uavsim replay, read back from {Path(rrd).name}", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m uavsim.viz.replay_png", description=__doc__.split("\n\n")[0])
    p.add_argument("source", nargs="?", default="datasets/small.h5", help="what to replay (session, dataset, run)")
    p.add_argument("out", nargs="?", default="docs/replay.png")
    p.add_argument("--class", dest="cls", type=int, default=None)
    p.add_argument("--episode", type=int, default=None)
    p.add_argument("--rrd", help="draw this existing replay recording instead of replaying SOURCE")
    a = p.parse_args(argv)
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    if a.rrd:
        if not Path(a.rrd).is_file():
            print(f"{a.rrd}: not found (a recording written by `uavsim replay --save`)", file=sys.stderr)
            return 2
        draw(a.rrd, a.out)
        return 0
    from uavsim.viz.replay import replay

    src = Path(a.source)
    if not src.exists():
        print(f"{src}: not found (`make demo` writes datasets/small.h5)", file=sys.stderr)
        return 2
    is_ds = src.suffix == ".h5"
    cls = a.cls if a.cls is not None else (1 if is_ds else None)
    ep = a.episode if a.episode is not None else (5 if is_ds else None)
    with tempfile.TemporaryDirectory() as tmp:
        rrd = Path(tmp) / "replay.rrd"
        try:
            s = replay(src, rrd, cls=cls, episode=ep)
        except UserError as exc:
            print(exc, file=sys.stderr)
            return 2
        run = s["runs"][0]
        what = f"{src.name} class {cls} episode {ep}" if is_ds else src.name
        draw(rrd, a.out, f"uavsim replay {what} ({run['kind']}, {run['extrema']} accepted extrema, "
                         f"u mismatch {run['u_mismatch']}), drawn from the .rrd read back")
    return 0


if __name__ == "__main__":
    sys.exit(main())
