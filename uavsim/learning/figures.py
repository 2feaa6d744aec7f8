"""Pictures of identification and training (PNG, matplotlib's Agg backend).

* ``identification_png``: the measured limit cycle beside the cycle the
  identified model gives under the same relay, and the measured point
  ``G(j w)`` on the model's Nyquist plot (``uavsim identify --plot``);
* ``training_curves_png``: training loss and validation mean J per epoch
  (``training.png`` beside every exported network).

    from uavsim.learning.figures import identification_png
    ans = identify_session("scenarios/sessions/altitude-npmrft", models="training/runs/small")
    identification_png("scenarios/sessions/altitude-npmrft", ans, "identify.png")
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["identification_png", "training_curves_png", "model_cycle"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def model_cycle(params: dict[str, float], family: str, beta: float, h: float, rate_hz: float,
                cycles: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The identified inner-loop model under a plain MRFT (``beta``, ``h``) at ``rate_hz``.

    Returns ``t`` (s), ``y`` and ``u`` of the last three cycles, ``t`` starting at the
    relay's last switch up before them (so measured and model cycles line up).
    """
    from uavsim.lumped.simulate import simulate_relay_batch

    # long enough for any class: the cycle is at most a few times the slowest lag plus the delay
    T = 2 * math.pi * max(params["T_prop"], params["T1"], 0.02) + 4 * params["tau"]
    n = int(max(cycles * T, 4.0) * rate_hz)
    sim = simulate_relay_batch(family, beta, h, 1.0 / rate_hz, n, K=params["K"], T_prop=params["T_prop"],
                               T1=params["T1"], tau=params["tau"])
    y, u = -sim["e"][0], sim["u"][0]
    return _last_cycles(y, u, rate_hz)


def _last_cycles(y: np.ndarray, u: np.ndarray, rate_hz: float, n: int = 3):
    ups = np.flatnonzero((u[1:] > u[:-1]) & (np.abs(u[1:] - u[:-1]) > 0))
    if ups.size < n + 1:
        t = np.arange(y.size) / rate_hz
        return t, y, u
    a, b = ups[-n - 1] + 1, ups[-1] + 1
    return np.arange(b - a) / rate_hz, y[a:b], u[a:b]


def identification_png(session: str | os.PathLike, ans: dict[str, Any], out: str | os.PathLike) -> Path:
    """Write the identification picture of ``ans`` (``identify_session``'s answer) for ``session``.

    Left: the measured y and u over the last two cycles of the steady segment
    identification used, y centred, and (inner loops) the identified model's own
    cycle under the run's relay (plain MRFT at the session's ``beta``, ``h``),
    aligned on the relay's switch up. Right: the identified model's Nyquist plot
    near the cycle, the measured point (held response with the zero-order hold
    removed) and the ray ``arg G = -pi + asin(beta)`` a relay puts the cycle on.
    """
    from uavsim.data.preprocess import INPUT_RATE_HZ, held_response
    from uavsim.formats.session import read_session
    from uavsim.lumped.frequency import freq_response_batch
    from uavsim.lumped.params import loop_family

    s = read_session(session)
    run = next(r for r in s.runs if r.spec.file == ans["run"])
    rate = float(s.control_rate_hz)
    osc = ans["oscillation"]
    # the segment identification used ends at ``stop`` (samples of the run): four cycles up to it
    b = int(osc["stop"])
    a = max(0, b - int(round(4 * float(osc["period"]) * rate)))
    y, u = np.asarray(run.data.y)[a:b], np.asarray(run.data.u)[a:b]
    t_m, y_m, u_m = _last_cycles(y, u, rate)
    fam = loop_family(s.loop)
    beta, h = float(run.spec.beta), float(run.spec.h)
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax1.plot(t_m, y_m - np.mean(y_m), color="C0", lw=1.6, label="measured y")
    p = ans["params"]
    inner = fam in ("altitude", "attitude")
    if inner:
        t_s, y_s, _ = model_cycle(p, fam, beta, h, rate)
        ax1.plot(t_s, y_s - np.mean(y_s), color="C1", lw=1.4, ls="--",
                 label=f"identified model, plain MRFT (beta {beta:g}, h {h:g})")
    ax1.set_xlabel("time since the relay's switch up (s)")
    ax1.set_ylabel("y - mean (output units)")
    ax1r = ax1.twinx()
    ax1r.step(t_m, u_m, where="post", color="0.6", lw=0.8)
    ax1r.set_ylabel("u (command units)", color="0.5")
    ax1.set_title(f"{s.loop}: measured cycle {osc['period']:.3g} s, amplitude {osc['amplitude']:.3g}")
    ax1.legend(loc="upper right", fontsize=7, framealpha=0.9)

    w0 = float(ans["response"]["omega"])
    resp = ans["response"]["gain"] * np.exp(1j * math.radians(ans["response"]["phase_deg"]))
    G = complex(resp / held_response(1.0, w0, INPUT_RATE_HZ))
    if inner:
        w = w0 * np.geomspace(0.4, 2.5, 400)
        Gm = freq_response_batch(fam, w, K=p["K"], T_prop=p["T_prop"], T1=p["T1"], tau=p["tau"])[0]
        ax2.plot(Gm.real, Gm.imag, color="C1", lw=1.4, label="identified model G(jw), 0.4-2.5 w")
        G0 = freq_response_batch(fam, np.array([w0]), K=p["K"], T_prop=p["T_prop"], T1=p["T1"], tau=p["tau"])[0, 0]
        ax2.plot([G0.real], [G0.imag], "o", mfc="none", color="C1", ms=9, label="model at the cycle's w")
    ax2.plot([G.real], [G.imag], "x", color="C0", ms=10, mew=2, label=f"measured, w = {w0:.3g} rad/s")
    r = 1.6 * abs(G)
    ph = -math.pi + math.asin(beta)
    ax2.plot([0, r * math.cos(ph)], [0, r * math.sin(ph)], color="0.5", lw=0.8, ls=":",
             label=f"relay ray, beta = {beta:g}")
    ax2.axhline(0, color="0.85", lw=0.6)
    ax2.axvline(0, color="0.85", lw=0.6)
    ax2.set_xlim(-r, 0.4 * r)
    ax2.set_ylim(*((-0.4 * r, r) if G.imag > 0 else (-r, 0.4 * r)))
    ax2.set_aspect("equal")
    ax2.set_xlabel("Re G")
    ax2.set_ylabel("Im G")
    who = f"class {ans['class']}" if ans["class"] is not None else "family member (no class)"
    ax2.set_title(f"{who}: K={p['K']:.3g}, tau={1e3 * p['tau']:.3g} ms")
    ax2.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def training_curves_png(history: list[dict[str, float]], out: str | os.PathLike, title: str = "",
                        best_epoch: int | None = None) -> Path:
    """Training loss and validation mean J (and top-1) per epoch, from the trainer's history."""
    plt = _pyplot()
    ep = [h["epoch"] + 1 for h in history]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.6))
    ax1.plot(ep, [h["loss"] for h in history], color="C0", marker=".")
    ax1.set_xlabel("epoch")
    ax1.set_ylabel("J-weighted loss (training)")
    ax1.set_yscale("log")
    ax2.plot(ep, [h["val_mean_J"] for h in history], color="C1", marker=".", label="validation mean J")
    ax2.set_xlabel("epoch")
    ax2.set_ylabel("mean J (1 = the right class)")
    if best_epoch is not None and best_epoch >= 0:
        for ax in (ax1, ax2):
            ax.axvline(best_epoch + 1, color="0.6", ls=":", lw=1)
        ax2.plot([], [], color="0.6", ls=":", label=f"best epoch {best_epoch + 1} (exported)")
    if all("val_top1" in h for h in history):
        ax2r = ax2.twinx()
        ax2r.plot(ep, [h["val_top1"] for h in history], color="C2", lw=0.8, alpha=0.7)
        ax2r.set_ylabel("validation top-1", color="C2")
        ax2r.set_ylim(0, 1.02)
    ax2.legend(loc="upper right", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
