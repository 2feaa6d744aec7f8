#!/usr/bin/env bash
# make_viewer_png.sh -- a real screenshot of the Rerun viewer showing a replayed
# relay limit cycle, written to docs/replay-viewer.png.
#
# Run by hand from anywhere (it finds the repository from its own path):
#     bash docs/make_viewer_png.sh
# It is NOT run by the tests, by CI or by `make`; it needs system packages the
# project does not otherwise need.
#
# What it does:
#   1. `uavsim replay --save` writes an .rrd recording (with the blueprint
#      uavsim ships: time series, phase portrait, 3D vehicle) of a noisy NP-MRFT
#      episode of datasets/small.h5 (DATASET, CLASS 1, EPISODE 5; `make demo`
#      writes the file), or, without it, of a 15 s relay session that
#      `uavsim sim relay --loop altitude` saves.
#   2. A screenshot blueprint (.rbl) is written: the same layout, rebuilt with
#      uavsim's own blueprint builder, with the blueprint and selection panels
#      hidden, the time panel collapsed and the time cursor at the end of the
#      recording. If that builder cannot be imported, the recording's own
#      blueprint is used as it is (panels shown, cursor near the start).
#   3. A virtual X server (Xvfb) is started and the real Rerun viewer binary is
#      run in it on Mesa's software Vulkan driver (lavapipe), with
#      `--screenshot-to`: the viewer renders itself at 2x, saves a PNG of its own
#      window and quits. (Grabbing the X root window with `import`/`xwd` does not
#      work here: lavapipe's frames never reach the Xvfb framebuffer, so those
#      grabs are black. The OpenGL backend fails outright on llvmpipe with
#      "Adapter does not support drawing to texture format R32Float".)
#   4. ImageMagick scales it to 1600x1000 and stores it as an 8-bit palette PNG
#      (about 250-300 KB).
# Xvfb and the viewer are started by this script and are killed on exit, also
# on error or Ctrl-C; the scratch folder under /tmp is removed (KEEP=1 keeps it).
#
# Needs (Debian 12; no GPU needed, takes about a minute on 2 cores):
#     apt-get install -y --no-install-recommends xvfb mesa-vulkan-drivers imagemagick
#   mesa-vulkan-drivers brings libvulkan1 and lavapipe. The viewer also loads the
#   X client libraries libxkbcommon-x11-0 libxcursor1 libxrandr2 libxi6 (already
#   present on the machine this was written on; install them if it complains).
#   The project's virtualenv (.venv, or VENV=...) with uavsim and rerun-sdk
#   installed; written against rerun-sdk 0.41.0.
#
# Environment knobs: VENV (default <repo>/.venv), OUT (default
# <repo>/docs/replay-viewer.png), DATASET, CLASS, EPISODE (the dataset episode),
# DURATION (length of the fallback relay episode, default 15),
# SIZE (viewer window in logical points, default 1600x1000), KEEP=1.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV=${VENV:-$ROOT/.venv}
OUT=${OUT:-$ROOT/docs/replay-viewer.png}
DURATION=${DURATION:-15}
SIZE=${SIZE:-1600x1000}
PY=$VENV/bin/python
export RERUN_ANALYTICS=0

for tool in Xvfb convert; do
    command -v "$tool" >/dev/null || {
        echo "error: $tool not found; apt-get install -y --no-install-recommends xvfb mesa-vulkan-drivers imagemagick" >&2
        exit 1
    }
done
ls /usr/share/vulkan/icd.d/lvp_icd.*.json >/dev/null 2>&1 || {
    echo "error: Mesa's lavapipe Vulkan driver is missing; apt-get install -y mesa-vulkan-drivers" >&2
    exit 1
}
[ -x "$PY" ] || { echo "error: no Python at $PY (set VENV)" >&2; exit 1; }

# The real viewer binary. `.venv/bin/rerun` is a Python wrapper that starts it
# as a child process, so killing the wrapper would leave the viewer running.
RERUN_BIN=$("$PY" -c 'import os, rerun_cli; print(os.path.join(os.path.dirname(rerun_cli.__file__), "rerun"))')
[ -x "$RERUN_BIN" ] || { echo "error: no rerun binary at $RERUN_BIN" >&2; exit 1; }

WORK=$(mktemp -d /tmp/uavsim-viewer-png.XXXXXX)
XVFB_PID=
VIEWER_PID=
cleanup() {
    local rc=$?
    trap - EXIT INT TERM
    # Only the processes this script started, by their PIDs.
    for pid in $VIEWER_PID $XVFB_PID; do
        if kill -0 "$pid" 2>/dev/null; then
            kill "$pid" 2>/dev/null || true
            for _ in 1 2 3 4 5 6 7 8 9 10; do kill -0 "$pid" 2>/dev/null || break; sleep 0.3; done
            kill -9 "$pid" 2>/dev/null || true
        fi
    done
    if [ "${KEEP:-0}" = 1 ]; then echo "scratch kept in $WORK"; else rm -rf "$WORK"; fi
    exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

echo "[1/4] recording (in $WORK)"
# The README's picture is a noisy NP-MRFT episode of the demo's training set
# (datasets/small.h5, class 1, episode 5, simulated again exactly); without that
# file (make demo writes it), a noise-free relay session of `uavsim sim relay`.
DATASET=${DATASET:-$ROOT/datasets/small.h5}
if [ -f "$DATASET" ]; then
    SRC=$DATASET
    (cd "$ROOT" && "$VENV/bin/uavsim" replay "$SRC" --class "${CLASS:-1}" --episode "${EPISODE:-5}" \
        --save "$WORK/replay.rrd")
else
    (cd "$ROOT" && "$VENV/bin/uavsim" sim relay --loop altitude --duration "$DURATION" --session "$WORK/sessions")
    SRC=$WORK/sessions/altitude
    (cd "$ROOT" && "$VENV/bin/uavsim" replay "$SRC" --save "$WORK/replay.rrd")
fi

echo "[2/4] screenshot blueprint"
RBL=$WORK/screenshot.rbl
if ! (cd "$ROOT" && "$PY" - "$SRC" "$RBL" "${CLASS:-1}" "${EPISODE:-5}" <<'EOF'
# The blueprint `uavsim replay` logs, with the panels around it hidden and the
# time cursor following the end of the recording. Uses uavsim internals
# (uavsim.viz.replay._blueprint): if they move, the caller falls back.
import sys
from pathlib import Path

import rerun.blueprint as rrb
from uavsim.viz.replay import APP_ID, TIMELINE, _blueprint
from uavsim.viz.sources import dataset_runs, session_runs

src = Path(sys.argv[1])
if src.suffix == ".h5":
    runs, _ = dataset_runs(src, int(sys.argv[3]), int(sys.argv[4]), resimulate=True)
else:
    runs, _ = session_runs(src, None, resimulate=True)
layout = _blueprint(runs)
rrb.Blueprint(
    layout.root_container,
    rrb.BlueprintPanel(state="hidden"),
    rrb.SelectionPanel(state="hidden"),
    rrb.TimePanel(state="collapsed", timeline=TIMELINE, play_state="following"),
    auto_layout=False,
    auto_views=False,
).save(APP_ID, sys.argv[2])
EOF
); then
    echo "warning: could not build the screenshot blueprint; using the recording's own" >&2
    RBL=
fi

echo "[3/4] Xvfb + Rerun viewer (software Vulkan), --screenshot-to"
# -displayfd: Xvfb picks a free display number and writes it once it is ready.
exec 3>"$WORK/display"
Xvfb -displayfd 3 -screen 0 "${SIZE}x24" -nolisten tcp >"$WORK/xvfb.log" 2>&1 &
XVFB_PID=$!
exec 3>&-
for _ in $(seq 100); do [ -s "$WORK/display" ] && break; sleep 0.1; done
[ -s "$WORK/display" ] || { echo "error: Xvfb did not start; see $WORK/xvfb.log" >&2; KEEP=1; exit 1; }
DISP=:$(tr -d '\n' <"$WORK/display")

# A free TCP port for the viewer's gRPC server (default 9876 may be taken).
PORT=$("$PY" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')

DISPLAY=$DISP "$RERUN_BIN" --renderer vulkan --window-size "$SIZE" --port "$PORT" \
    --screenshot-to "$WORK/viewer.png" "$WORK/replay.rrd" ${RBL:+"$RBL"} \
    >"$WORK/viewer.log" 2>&1 &
VIEWER_PID=$!
# The viewer quits by itself once the screenshot is saved (about 10-15 s here).
for _ in $(seq 1200); do kill -0 "$VIEWER_PID" 2>/dev/null || break; sleep 0.1; done
if kill -0 "$VIEWER_PID" 2>/dev/null || [ ! -s "$WORK/viewer.png" ]; then
    echo "error: the viewer did not save a screenshot within 120 s; last lines of its log:" >&2
    tail -n 15 "$WORK/viewer.log" >&2
    KEEP=1
    exit 1
fi

echo "[4/4] $OUT"
convert "$WORK/viewer.png" -resize "$SIZE" -strip -colors 256 "PNG8:$OUT"
identify "$OUT"
ls -l "$OUT"
