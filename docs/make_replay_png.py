"""Draw docs/replay.png: a replayed limit cycle, from a session and the recomputed relay.

The same data ``uavsim replay`` logs to Rerun (signals, switches, accepted
extrema, tau_obs windows, phase portrait), drawn with matplotlib because the
Rerun viewer cannot open a window on a headless machine.

    .venv/bin/python docs/make_replay_png.py scenarios/sessions/altitude-npmrft docs/replay.png
"""

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from uavsim.formats.session import read_session  # noqa: E402
from uavsim.viz.replay import phase_portrait, recompute_relay  # noqa: E402


def main(session_path: str, out: str) -> None:
    s = read_session(session_path)
    run = next(r for r in s.runs if r.spec.kind in ("np-mrft", "mrft"))
    t, y, r, u = run.data.t, run.data.y, run.data.r, run.data.u
    e = r - y
    rep = recompute_relay(run, s.control_rate_hz)
    lo = t[-1] - 4.0  # the last four seconds: the settled cycle
    m = t >= lo
    fig, ax = plt.subplots(3, 1, figsize=(9, 7), sharex=False, gridspec_kw={"height_ratios": [2, 1, 2]})
    ax[0].plot(t[m], e[m], lw=1, label="e = r - y")
    for a, b in rep.windows:
        if t[b] >= lo:
            ax[0].axvspan(max(t[a], lo), t[b], color="0.85", lw=0)
    k = rep.switch_idx[t[rep.switch_idx] >= lo]
    ax[0].plot(t[k], e[k], "v", color="C3", ms=5, label="switch")
    ke = rep.ext_idx[t[rep.ext_idx] >= lo]
    ax[0].plot(t[ke], e[ke], "o", mfc="none", color="C2", ms=6, label="accepted extremum")
    ax[0].set_ylabel("e (m)")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[0].set_title(f"{s.loop} {run.spec.kind}, beta={run.spec.beta}, tau_obs={run.spec.tau_obs} s (grey: inhibition)")
    ax[1].step(t[m], u[m], where="post", color="C1")
    ax[1].set_ylabel("u")
    ax[1].set_xlabel("t (s)")
    pp = phase_portrait(t[m], e[m])
    ax[2].plot(pp[:, 0], pp[:, 1], lw=0.8)
    ax[2].set_xlabel("e (m)")
    ax[2].set_ylabel("de/dt (m/s)")
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(*(sys.argv[1:3] if len(sys.argv) >= 3 else ("scenarios/sessions/altitude-npmrft", "docs/replay.png")))
