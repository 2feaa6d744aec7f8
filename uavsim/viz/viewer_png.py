"""A real screenshot of the Rerun viewer showing a replayed relay limit cycle (``docs/replay-viewer.png``).

Run by hand from the repository root; it is not run by the tests, by CI or by
``make``: it needs system packages the project does not otherwise need.

    python -m uavsim.viz.viewer_png                        # -> docs/replay-viewer.png
    python -m uavsim.viz.viewer_png --out /tmp/viewer.png --dataset datasets/small.h5 --class 1 --episode 5

What it does:

1. ``uavsim replay --save`` writes an ``.rrd`` recording (with the blueprint
   uavsim ships: time series, phase portrait, 3D vehicle) of a noisy NP-MRFT
   episode of ``datasets/small.h5`` (class 1, episode 5; ``make demo`` writes
   the file) or, without it, of a 15 s relay session that
   ``uavsim sim relay --loop altitude`` saves.
2. A screenshot blueprint (``.rbl``) is written: the same layout, rebuilt with
   uavsim's own blueprint builder, with the blueprint and selection panels
   hidden, the time panel collapsed and the time cursor at the end of the
   recording. If that builder fails, the recording's own blueprint is used as
   it is (panels shown, cursor near the start).
3. A virtual X server (Xvfb) is started and the real Rerun viewer binary is run
   in it on Mesa's software Vulkan driver (lavapipe) with ``--screenshot-to``:
   the viewer renders itself at 2x, saves a PNG of its own window and quits.
   (Grabbing the X root window with ``import``/``xwd`` does not work: lavapipe's
   frames never reach the Xvfb framebuffer, so those grabs are black. The
   OpenGL backend fails outright on llvmpipe with "Adapter does not support
   drawing to texture format R32Float".)
4. ImageMagick scales it to the window size and stores it as an 8-bit palette
   PNG (about 250-300 KB).

Xvfb and the viewer are started here and killed on exit, also on error or
Ctrl-C (by their process ids); the scratch folder under /tmp is removed
(``--keep`` keeps it).

Needs (Debian 12; no GPU, about a minute on 2 cores)::

    apt-get install -y --no-install-recommends xvfb mesa-vulkan-drivers imagemagick

``mesa-vulkan-drivers`` brings libvulkan1 and lavapipe. The viewer also loads
the X client libraries libxkbcommon-x11-0 libxcursor1 libxrandr2 libxi6
(install them if it complains). Written against rerun-sdk 0.41.0.
"""

from __future__ import annotations

import argparse
import glob
import os
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

APT = "apt-get install -y --no-install-recommends xvfb mesa-vulkan-drivers imagemagick"


class Missing(Exception):
    """A requirement of the screenshot is missing (one line, exit 2)."""


def check_requirements() -> str:
    """The Rerun viewer binary, after checking Xvfb, ImageMagick and lavapipe; raises ``Missing``."""
    for tool in ("Xvfb", "convert"):
        if shutil.which(tool) is None:
            raise Missing(f"{tool} not found; {APT}")
    if not glob.glob("/usr/share/vulkan/icd.d/lvp_icd.*.json"):
        raise Missing("Mesa's lavapipe Vulkan driver is missing; apt-get install -y mesa-vulkan-drivers")
    try:
        import rerun_cli
    except ImportError as exc:
        raise Missing(f"rerun-sdk is not installed in this Python ({exc})") from None
    # The real viewer binary: the ``rerun`` script is a Python wrapper that starts it as a child
    # process, so killing the wrapper would leave the viewer running.
    binary = os.path.join(os.path.dirname(rerun_cli.__file__), "rerun")
    if not os.access(binary, os.X_OK):
        raise Missing(f"no rerun binary at {binary}")
    return binary


def _uavsim(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "uavsim", *args], check=True)


def record(work: Path, dataset: Path, cls: int, episode: int, duration: float) -> tuple[Path, Path]:
    """Step 1: the replay recording ``work/replay.rrd``; returns (source, recording)."""
    rrd = work / "replay.rrd"
    if dataset.is_file():
        src = dataset
        _uavsim("replay", str(src), "--class", str(cls), "--episode", str(episode), "--save", str(rrd))
    else:
        _uavsim("sim", "relay", "--loop", "altitude", "--duration", f"{duration:g}", "--session", str(work / "sessions"))
        src = work / "sessions" / "altitude"
        _uavsim("replay", str(src), "--save", str(rrd))
    return src, rrd


def screenshot_blueprint(src: Path, out: Path, cls: int, episode: int) -> None:
    """Step 2: the layout ``uavsim replay`` logs, panels hidden, the time cursor following the end.

    The blueprint is ``uavsim.viz.replay.replay_blueprint``; the caller falls back if this fails.
    """
    import rerun.blueprint as rrb

    from uavsim.viz.replay import APP_ID, TIMELINE, replay_blueprint
    from uavsim.viz.sources import dataset_runs, session_runs

    if src.suffix == ".h5":
        runs, _ = dataset_runs(src, cls, episode, resimulate=True)
    else:
        runs, _ = session_runs(src, None, resimulate=True)
    layout = replay_blueprint(runs)
    rrb.Blueprint(
        layout.root_container,
        rrb.BlueprintPanel(state="hidden"),
        rrb.SelectionPanel(state="hidden"),
        rrb.TimePanel(state="collapsed", timeline=TIMELINE, play_state="following"),
        auto_layout=False,
        auto_views=False,
    ).save(APP_ID, str(out))


def _free_port() -> int:
    """A free TCP port for the viewer's gRPC server (the default 9876 may be taken)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stop(proc: subprocess.Popen | None) -> None:
    """End a process this module started, by its id: TERM, then KILL after 3 s."""
    if proc is None or proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(3.0)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def shoot(binary: str, work: Path, rrd: Path, rbl: Path | None, size: str) -> Path:
    """Step 3: Xvfb + the viewer on software Vulkan with ``--screenshot-to``; returns the raw PNG."""
    png = work / "viewer.png"
    xvfb = viewer = None
    try:
        # -displayfd: Xvfb picks a free display number and writes it once it is ready.
        rfd, wfd = os.pipe()
        with open(work / "xvfb.log", "wb") as log:
            xvfb = subprocess.Popen(["Xvfb", "-displayfd", str(wfd), "-screen", "0", f"{size}x24", "-nolisten", "tcp"],
                                    stdout=log, stderr=log, pass_fds=(wfd,))
        os.close(wfd)
        with os.fdopen(rfd) as r:
            display = r.readline().strip()
        if not display:
            raise Missing(f"Xvfb did not start; see {work / 'xvfb.log'}")
        cmd = [binary, "--renderer", "vulkan", "--window-size", size, "--port", str(_free_port()),
               "--screenshot-to", str(png), str(rrd)] + ([str(rbl)] if rbl else [])
        with open(work / "viewer.log", "wb") as log:
            viewer = subprocess.Popen(cmd, stdout=log, stderr=log, env={**os.environ, "DISPLAY": f":{display}"})
        # The viewer quits by itself once the screenshot is saved (about 10-15 s on 2 cores).
        try:
            viewer.wait(120.0)
        except subprocess.TimeoutExpired:
            pass
        if viewer.poll() is None or not png.is_file() or png.stat().st_size == 0:
            tail = (work / "viewer.log").read_text(errors="replace").splitlines()[-15:]
            print("\n".join(tail), file=sys.stderr)
            raise Missing(f"the viewer did not save a screenshot within 120 s; its log: {work / 'viewer.log'}")
        return png
    finally:
        _stop(viewer)
        _stop(xvfb)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uavsim.viz.viewer_png", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/replay-viewer.png", help="the PNG (default docs/replay-viewer.png)")
    ap.add_argument("--dataset", default="datasets/small.h5",
                    help="dataset of the episode (default datasets/small.h5; missing: a relay session instead)")
    ap.add_argument("--class", dest="cls", type=int, default=1, help="class of the dataset episode (default 1)")
    ap.add_argument("--episode", type=int, default=5, help="episode of that class (default 5)")
    ap.add_argument("--duration", type=float, default=15.0, help="length of the fallback relay session, s (default 15)")
    ap.add_argument("--size", default="1600x1000", help="viewer window, logical points (default 1600x1000)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder")
    args = ap.parse_args(argv)
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    work = Path(tempfile.mkdtemp(prefix="uavsim-viewer-png."))
    keep = args.keep
    try:
        binary = check_requirements()
        print(f"[1/4] recording (in {work})", flush=True)
        src, rrd = record(work, Path(args.dataset), args.cls, args.episode, args.duration)
        print("[2/4] screenshot blueprint", flush=True)
        rbl: Path | None = work / "screenshot.rbl"
        try:
            screenshot_blueprint(src, rbl, args.cls, args.episode)
        except Exception as exc:  # the recording's own blueprint still gives a picture
            print(f"warning: could not build the screenshot blueprint ({exc}); using the recording's own",
                  file=sys.stderr)
            rbl = None
        print("[3/4] Xvfb + Rerun viewer (software Vulkan), --screenshot-to", flush=True)
        png = shoot(binary, work, rrd, rbl, args.size)
        print(f"[4/4] {args.out}", flush=True)
        subprocess.run(["convert", str(png), "-resize", args.size, "-strip", "-colors", "256", f"PNG8:{args.out}"],
                       check=True)
        subprocess.run(["identify", args.out], check=False)
        return 0
    except Missing as exc:
        keep = keep or (work / "xvfb.log").exists()
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except subprocess.CalledProcessError as exc:
        print(f"error: {' '.join(map(str, exc.cmd[:4]))} ... exited with {exc.returncode}", file=sys.stderr)
        return 2
    finally:
        if keep:
            print(f"scratch kept in {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
