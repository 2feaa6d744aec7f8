"""Identification of a flight session with a trained network (DNN-NP-MRFT).

From a session (``uavsim-session/1``) with an ``np-mrft`` (or ``mrft``) run:

1. extract the last steady cycle exactly as the training sets were built
   (``uavsim.data.preprocess.features``: same resampling to 200 Hz, same edges,
   same normalization, same input length);
2. predict the class with the exported network of the loop's family
   (``uavsim.learning.export.Predictor``);
3. recover the gain from the loop's fundamental response: the ratio ``Y1 / (h U1)``
   of the first harmonics of y and of the command over the last steady cycles
   (``CycleFeatures.response``) is the process's ``K G_n(j w)`` at the cycle's
   frequency ``w``, whatever the relay's bias, ``tau_obs``, ``a_n`` and the
   sampling did to the cycle, so ``K_hat = |response| / |G_class(j w)|`` with
   the identified class's unit-gain model (``recover_gain``). (The authors'
   ``K_hat = (a / h) / a_class``, from the plain continuous MRFT's amplitude,
   is biased by tens of percent by exactly those; ``uavsim.learning.evaluate``
   reports both.)
4. scale the class's rule gains (for K = 1) to the real process:
   ``kp = kp_class / K_hat``, ``kd = kd_class / K_hat``.

A session without a usable oscillation (too short for two cycles, no
switching, a relay command that is not +-h, a flat or saturated output) is an
error (``NoOscillation``, a ``UserError``), never a guess.

    from uavsim.learning.identify import identify_session, write_model
    ans = identify_session("scenarios/sessions/altitude-npmrft", model_dir="training/runs/small")
    ans["class"], ans["params"]["K"], ans["gains"]["kp"]
    write_model("scenarios/sessions/altitude-npmrft", ans)      # adds the [model] table
"""

from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.learning.export import META_FILE, Predictor

__all__ = ["default_model_root", "resolve_model_dir", "identify_session", "identify_arrays", "write_model",
           "recover_gain", "class_gain_at", "SATURATION_FRACTION"]

#: a cycle whose output sits at its top or bottom level this fraction of the time is clipped, not a relay cycle
SATURATION_FRACTION = 0.35
_SAT_BAND = 0.005  # of the peak-to-peak: "at the extreme level"

_predictors: dict[str, Predictor] = {}


def default_model_root() -> Path:
    """``$UAVSIM_MODELS`` or ``training/runs`` of the repository (where ``uavsim train`` writes)."""
    env = os.environ.get("UAVSIM_MODELS")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "training" / "runs"


def resolve_model_dir(family: str, model_dir: str | os.PathLike | None = None) -> Path:
    """The exported model folder for a loop family.

    ``model_dir`` may be a model folder itself (holding ``meta.json``) or a root
    with one folder per family (``altitude/``, ``attitude/``).
    """
    root = Path(model_dir) if model_dir is not None else default_model_root()
    if (root / META_FILE).is_file():
        return root
    if (root / family / META_FILE).is_file():
        return root / family
    raise UserError(f"no trained {family} network under {root} (run `make train` or pass --models DIR)")


def _predictor(d: Path) -> Predictor:
    key = str(d.resolve())
    if key not in _predictors:
        _predictors[key] = Predictor(d)
    return _predictors[key]


def class_gain_at(table: dict[str, Any], cls: np.ndarray, family: str, omega: np.ndarray,
                  rate_hz: float) -> np.ndarray:
    """``|G(j w)|`` of unit-gain class models as a controller at ``rate_hz`` samples them.

    The command is held between samples, which scales the fundamental the
    output sees by ``sinc(w Ts / 2)`` against the command's samples.

    Parameters
    ----------
    table : class table (``T_prop``, ``T1``, ``tau`` columns, (n_classes,))
    cls : (m,) int, classes
    family : ``"altitude"`` or ``"attitude"``
    omega : (m,) rad/s, frequency of each
    rate_hz : float, rate of the samples the response was measured on

    Returns
    -------
    (m,) output units per command unit
    """
    from uavsim.lumped.frequency import freq_response_batch

    if family not in ("altitude", "attitude"):
        raise UserError(f"gain recovery from the response needs an inner-loop class table, not {family!r}")
    cls = np.asarray(cls, dtype=np.int64)
    w = np.asarray(omega, dtype=np.float64).reshape(-1, 1)
    par = {k: np.asarray(table[k], dtype=np.float64)[cls] for k in ("T_prop", "T1", "tau")}
    g = np.abs(freq_response_batch(family, w, K=1.0, **par))[:, 0]
    x = w[:, 0] / (2.0 * rate_hz)
    return g * np.sinc(x / np.pi)


def recover_gain(response: np.ndarray, response_period: np.ndarray, cls: np.ndarray, table: dict[str, Any],
                 family: str, rate_hz: float | None = None) -> np.ndarray:
    """``K_hat = |response| / |G_class(j w)|``, ``w = 2 pi / response_period`` (see module docstring).

    Parameters
    ----------
    response : (m,) complex, ``CycleFeatures.response`` (output units per command unit)
    response_period : (m,) s
    cls : (m,) int, identified classes
    table : class table
    family : ``"altitude"`` or ``"attitude"``
    rate_hz : rate of the samples the response was measured on (default ``INPUT_RATE_HZ``)

    Returns
    -------
    (m,) K_hat
    """
    from uavsim.data.preprocess import INPUT_RATE_HZ

    w = 2.0 * np.pi / np.asarray(response_period, dtype=np.float64)
    return np.abs(np.asarray(response)) / class_gain_at(table, cls, family, w, rate_hz or INPUT_RATE_HZ)


def _check_not_saturated(y: np.ndarray) -> None:
    """Reject a cycle whose output is clipped (sits at its extreme level for long)."""
    hi, lo = float(y.max()), float(y.min())
    band = _SAT_BAND * (hi - lo)
    for name, frac in (("top", np.mean(y >= hi - band)), ("bottom", np.mean(y <= lo + band))):
        if frac > SATURATION_FRACTION:
            from uavsim.data.preprocess import NoOscillation

            raise NoOscillation(f"output saturated: the cycle sits at its {name} level {100 * frac:.0f}% of the time")


def identify_arrays(y: np.ndarray, u: np.ndarray, rate_hz: float, h: float, bias: float, predictor: Predictor,
                    beta: float | None = None) -> dict[str, Any]:
    """Identify from raw traces (control-rate samples).

    Parameters
    ----------
    y, u : (T,) measurement and relay command as the controller saw/computed them
    rate_hz : float
        Control rate, Hz.
    h, bias : float
        Relay amplitude and bias, command units.
    predictor : Predictor
        Exported network of the loop's family.
    beta : float or None
        The run's MRFT parameter; must match the network's (checked when given).

    Returns
    -------
    dict with ``class``, ``params`` (K, T_prop, T1, tau), ``gains`` (kp, kd,
    derivative_filter_hz, for the identified K) and ``oscillation`` (period s,
    amplitude output units, n_cycles, start, stop).
    """
    from uavsim.data.preprocess import features

    meta = predictor.meta
    if beta is not None and meta.get("beta") is not None and abs(float(beta) - float(meta["beta"])) > 1e-6:
        raise UserError(f"the run used beta={beta} but the {meta['loop']} network was trained at beta={meta['beta']}")
    f = features(y, u, rate_hz, h, bias, predictor.input_length, cycles=int(meta.get("cycles", 1)))
    seg = np.asarray(y, dtype=np.float64)[f.start : f.stop]
    if seg.size >= 4:
        _check_not_saturated(seg)
    cls_arr, act = predictor.predict(f.x)
    c = int(cls_arr[0])
    tab = meta["classes"]
    K_hat = float(recover_gain(np.array([f.response]), np.array([f.response_period]), cls_arr, tab, meta["loop"])[0])
    if not (math.isfinite(K_hat) and K_hat > 0):
        raise UserError(f"cannot recover the gain: fundamental response {f.response} over {f.response_cycles} cycles")
    params = {"K": K_hat}
    for k in ("T_prop", "T1", "T2", "tau"):
        if k in tab:
            params[k] = float(tab[k][c])
    gains = {"kp": float(tab["kp"][c]) / K_hat, "kd": float(tab["kd"][c]) / K_hat,
             "derivative_filter_hz": float(tab["derivative_filter_hz"][c])}
    a = act[0].astype(np.float64)
    p = np.exp(a - a.max())
    p /= p.sum()
    return {
        "loop": meta["loop"],
        "class": c,
        "params": params,
        "gains": gains,
        "oscillation": {"period": f.period, "amplitude": f.amplitude, "n_cycles": f.n_cycles,
                        "start": f.start, "stop": f.stop},
        "softmax_top": float(p[c]),
        "response": {"gain": abs(f.response), "phase_deg": math.degrees(np.angle(f.response)),
                     "omega": 2 * math.pi / f.response_period, "n_cycles": f.response_cycles},
    }


def identify_session(path: str | os.PathLike, model_dir: str | os.PathLike | None = None,
                     run: str | None = None) -> dict[str, Any]:
    """Identify the loop of a session from its relay run (see module docstring).

    Parameters
    ----------
    path : path-like
        Session folder (or its ``session.toml``).
    model_dir : path-like or None
        Exported model folder or a root with ``altitude/``, ``attitude/`` (default ``default_model_root()``).
    run : str or None
        File name of the run to use (default: the first np-mrft run, else the first mrft run).

    Returns
    -------
    dict
        The JSON of ``uavsim identify --json`` (session.md): ``loop``, ``class``,
        ``params``, ``gains``, plus ``oscillation``, ``run``, ``model_dir``,
        ``had_model``.
    """
    from uavsim.formats.session import read_session
    from uavsim.lumped.params import loop_family

    s = read_session(path)
    fam = loop_family(s.loop)
    if fam == "lateral":
        raise UserError("lateral identification needs the attitude class and its lateral network; not supported yet")
    relays = [r for r in s.runs if r.spec.kind in ("np-mrft", "mrft")]
    if run is not None:
        relays = [r for r in relays if r.spec.file == run]
        if not relays:
            raise UserError(f"session {path}: no np-mrft/mrft run with file {run!r}")
    if not relays:
        raise UserError(f"session {path}: no np-mrft or mrft run to identify from")
    relays.sort(key=lambda r: r.spec.kind != "np-mrft")
    r = relays[0]
    d = resolve_model_dir(fam, model_dir)
    pred = _predictor(d)
    if pred.meta.get("loop") not in (fam, s.loop):
        raise UserError(f"{d} holds a {pred.meta.get('loop')} network, the session is {s.loop}")
    ans = identify_arrays(r.data.y, r.data.u, s.control_rate_hz, float(r.spec.h), float(r.spec.bias or 0.0), pred,
                          beta=r.spec.beta)
    ans["loop"] = s.loop
    ans["run"] = r.spec.file
    ans["model_dir"] = str(d)
    ans["had_model"] = s.model is not None
    # NP-MRFT a_n is a noise amplitude (2 std for Gaussian noise, uavsim.noise.models)
    ans["noise_std"] = float(r.spec.a_n or 0.0) / 2.0
    return ans


def write_model(path: str | os.PathLike, ans: dict[str, Any], overwrite: bool = False) -> Path:
    """Write the identified model as the session's ``[model]`` table.

    Refuses to replace an existing ``[model]`` unless ``overwrite``.
    """
    from uavsim.formats.session import ModelSpec, read_session, write_session

    s = read_session(path)
    if s.model is not None and not overwrite:
        raise UserError(f"session {path} already has a [model]; pass --force to replace it")
    p = ans["params"]
    model = ModelSpec(K=float(p["K"]), T_prop=float(p["T_prop"]), T1=float(p["T1"]), tau=float(p["tau"]),
                      T2=p.get("T2"), noise_std=float(ans.get("noise_std", 0.0)))
    folder = Path(path)
    if folder.name == "session.toml":
        folder = folder.parent
    return write_session(replace(s, model=model), folder)
