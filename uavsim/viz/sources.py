"""What ``uavsim replay`` can replay, read into one shape: :class:`ReplayRun`.

Three sources, told apart by :func:`detect_source`:

* **session** (a folder with ``session.toml``, format ``uavsim-session/2`` or 1):
  every run, r, y, u as logged. A session whose ``[model]`` is noise-free and
  has no effects (what ``uavsim sim relay --session`` writes) is simulated
  again with ``LoopBatch(record_state=True)`` at the physics steps ``uavsim``
  uses (0.5 ms, 1 ms) from the logged first output; when that reproduces the
  logged ``y`` (within 1e-6 of its peak-to-peak) the run gets the vehicle's
  pose and rotor thrusts, otherwise the log says why not.
* **dataset** (``uavsim-dataset/1`` HDF5, ``--class C --episode E``): the
  ``E``-th kept episode of label ``C``. The file records the recipe text,
  its seed, the grid hash and every draw, so the episode's whole chunk is
  simulated again exactly as ``uavsim generate`` did (same plan, chunk seed,
  effects and NP-MRFT) with the state recorded; the re-simulation is checked
  against the stored network input (and raw traces when the recipe kept
  them). That gives the noisy ``y`` the relay saw, the noise-free ``y_true``
  and the pose. When the grid is missing or changed, or the draws do not
  match, the log says so and the replay shows what the file holds (raw
  traces, else the network input).
* **scenario** (``x.rrd`` of ``uavsim scenario run`` with its ``x.run.npz``,
  or the ``.run.npz`` itself): every episode (relay, step, test) with ``y`` as
  the controller saw it, ``y_true``, the vision signals and the pose.

    from uavsim.viz.sources import dataset_runs
    runs, info = dataset_runs("datasets/small.h5", cls=2, episode=0)
    runs[0].y_true.shape, runs[0].qpos.shape          # (T,), (T, 6)
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.formats.session import MRFT_RUN, NP_MRFT_RUN, RELAY_KINDS

#: physics steps tried when re-simulating a session (``uavsim sim relay`` default first)
SESSION_DT = (0.0005, 0.001)
#: a re-simulated session must reproduce the logged y within this fraction of its peak-to-peak
SESSION_TOL = 1e-6
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


@dataclass
class ReplayRun:
    """One episode to replay, whatever its source.

    Attributes
    ----------
    stem : str
        Entity name: the run is logged under ``runs/<stem>``.
    label : str
        Where it comes from (run file, ``FILE class C episode E``, scenario episode name).
    kind : str
        ``np-mrft``, ``mrft`` (relay runs), ``step``, ``pd`` or ``scheduled-pd``.
    t : (T,) s
    r, y, u : (T,)
        Reference, measurement as the controller saw it (output units), command.
    rate_hz : float
        Control rate, Hz.
    relay : dict or None
        ``beta, h, tau_obs, a_n, bias`` of a relay run (``tau_obs``, ``a_n`` None for MRFT).
    y_true : (T,) or None
        Noise-free output (simulations).
    qpos, rotor_force : (T, 6) or None
        Vehicle joint positions (m, rad) and rotor thrusts (N) (simulations).
    signals : dict name -> (T,)
        Other signals to plot (vision chain, raw file traces, ...).
    notes : list of (level, text)
        Log lines about the source (``INFO``/``WARN``), logged before the relay check.
    info : dict
        Extra summary fields.
    """

    stem: str
    label: str
    kind: str
    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    rate_hz: float
    relay: dict[str, Any] | None = None
    y_true: np.ndarray | None = None
    qpos: np.ndarray | None = None
    rotor_force: np.ndarray | None = None
    signals: dict[str, np.ndarray] = field(default_factory=dict)
    notes: list[tuple[str, str]] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)


def entity_stem(name: str) -> str:
    """Entity-path-safe stem of a run file or name (``"a/mrft b.csv"`` -> ``"mrft_b"``)."""
    stem = Path(name).stem or "run"
    return re.sub(r"[^A-Za-z0-9_\-]", "_", stem)


def detect_source(path: str | Path) -> str:
    """``"session"``, ``"dataset"`` or ``"scenario"`` for a replay path.

    A folder is a session (or a scenario run when it holds exactly one
    ``*.run.npz`` and no ``session.toml``); ``.h5``/``.hdf5`` or an HDF5 file is
    a dataset; ``.run.npz`` or an ``.rrd`` with one beside it is a scenario run.
    Anything else is read as a session so that its error names the problem.
    """
    p = Path(path)
    if p.is_dir():
        if not (p / "session.toml").exists() and len(list(p.glob("*.run.npz"))) == 1:
            return "scenario"
        return "session"
    if p.name.endswith(".run.npz") or p.suffix == ".rrd":
        return "scenario"
    if p.suffix in (".h5", ".hdf5"):
        return "dataset"
    if p.is_file():
        try:
            with open(p, "rb") as f:
                if f.read(8) == _HDF5_MAGIC:
                    return "dataset"
        except OSError:
            pass
    return "session"


# -- sessions ---------------------------------------------------------------------------------------

def _relay_of(spec: Any, reading: int) -> dict[str, Any] | None:
    if spec.kind not in RELAY_KINDS:
        return None
    return {"beta": spec.beta, "h": spec.h, "tau_obs": spec.tau_obs, "a_n": spec.a_n, "bias": spec.bias,
            "reading": reading}


def _resimulate_session_run(session: Any, rr: ReplayRun) -> ReplayRun:
    """Add the pose when the session's model, simulated again, reproduces the run (see module docstring)."""
    from uavsim.control.relay import MRFT, NPMRFT
    from uavsim.lumped.params import LumpedParams
    from uavsim.sim.runner import LoopBatch

    m = session.model
    why = None
    if m is None:
        why = "the session has no [model]"
    elif m.noise_std or session.effects:
        why = "its model has noise or effects (a flight or a noisy simulation)"
    elif session.loop not in ("altitude", "roll", "pitch"):
        why = f"{session.loop} sessions do not record the attitude loop they cascade over"
    elif rr.relay is None:
        why = "only relay runs are simulated again"
    elif np.any(rr.r != 0) or abs(rr.t[0]) > 1e-12 or not np.allclose(np.diff(rr.t), 1.0 / rr.rate_hz):
        why = "the run has a reference or an irregular clock"
    if why is not None:
        rr.notes.append(("INFO", f"{rr.label}: no vehicle pose: {why}"))
        return rr
    params = LumpedParams(session.loop, K=m.K, T_prop=m.T_prop, T1=m.T1, tau=m.tau)
    s = rr.relay
    ptp = float(np.ptp(rr.y)) or 1.0
    best = math.inf
    for dt in SESSION_DT:
        try:
            lb = LoopBatch([params], dt=dt, rate_hz=rr.rate_hz, y0=rr.y[:1], record_state=True)
        except UserError:
            continue
        relay = (MRFT(s["beta"], s["h"], rr.rate_hz, 1, bias=s["bias"], reading=s["reading"]) if rr.kind == MRFT_RUN
                 else NPMRFT(s["beta"], s["h"], s["tau_obs"], s["a_n"], rr.rate_hz, 1, bias=s["bias"],
                             reading=s["reading"]))
        res = lb.run(relay, rr.t.size / rr.rate_hz)
        if res.diverged[0]:
            continue
        err = float(np.max(np.abs(res.y[0] - rr.y)))
        best = min(best, err)
        if err <= SESSION_TOL * ptp:
            rr.y_true, rr.qpos, rr.rotor_force = res.y_true[0], res.qpos[0], res.rotor_force[0]
            rr.notes.append(("INFO", f"{rr.label}: simulated again from the session's [model] (dt = {dt} s, "
                                     f"y0 = {rr.y[0]:.6g}): y reproduced within {err:.2g}; vehicle pose logged"))
            rr.info["resimulated"] = {"dt": dt, "max_abs_y_error": err}
            return rr
    rr.notes.append(("INFO", f"{rr.label}: no vehicle pose: the session's [model] simulated again does not "
                             f"reproduce the logged y (best max error {best:.3g}; a flight, or other settings)"))
    return rr


def session_runs(path: str | Path, run: str | None = None, *, resimulate: bool = True
                 ) -> tuple[list[ReplayRun], dict[str, Any]]:
    """The runs of a session (all, or the one whose file or stem is ``run``).

    Returns
    -------
    runs : list of ReplayRun
    info : dict
        ``session`` (folder), ``loop``, ``control_rate_hz``.

    Raises
    ------
    UserError
        Malformed session or unknown run.
    """
    from uavsim.formats.session import read_session

    session = read_session(path)
    chosen = list(session.runs)
    if run is not None:
        chosen = [r for r in session.runs if run in (r.spec.file, Path(r.spec.file).name, Path(r.spec.file).stem)]
        if not chosen:
            names = ", ".join(r.spec.file for r in session.runs)
            raise UserError(f"no run {run!r} in session {session.path} (runs: {names})")
        chosen = chosen[:1]
    out: list[ReplayRun] = []
    stems: list[str] = []
    for r in chosen:
        stem = entity_stem(r.spec.file)
        while stem in stems:
            stem += "_"
        stems.append(stem)
        d = r.data
        rr = ReplayRun(stem=stem, label=r.spec.file, kind=r.spec.kind, t=d.t, r=d.r, y=d.y, u=d.u,
                       rate_hz=session.control_rate_hz, relay=_relay_of(r.spec, session.reading), info={"file": r.spec.file})
        out.append(_resimulate_session_run(session, rr) if resimulate else rr)
    return out, {"session": str(session.path), "loop": session.loop, "control_rate_hz": session.control_rate_hz}


# -- datasets ---------------------------------------------------------------------------------------

def _pick_row(ds: Any, cls: int, episode: int) -> int:
    path = ds.path
    if not 0 <= cls < ds.n_classes:
        raise UserError(f"dataset {path}: class {cls} out of range 0..{ds.n_classes - 1}")
    rows = np.flatnonzero(ds.labels == cls)
    if rows.size == 0:
        raise UserError(f"dataset {path}: class {cls} has no kept episodes")
    if not 0 <= episode < rows.size:
        raise UserError(f"dataset {path}: episode {episode} out of range 0..{rows.size - 1} for class {cls}")
    return int(rows[episode])


def _resimulate_chunk(ds: Any, row: int) -> tuple[dict[str, np.ndarray] | None, str]:
    """Simulate the chunk of dataset row ``row`` again, as ``uavsim generate`` did.

    Returns
    -------
    traces : dict or None
        ``y``, ``u``, ``y_true`` (T,), ``qpos``, ``rotor_force`` (T, 6), ``x`` (C, L)
        network input recomputed, ``chunk`` (index), ``chunk_size``; None when it
        cannot be done exactly.
    why : str
        What was done, or why not.
    """
    from uavsim.control.relay import READING
    from uavsim.data import preprocess
    from uavsim.data.generate import (
        RefiningRelay,
        chunk_params,
        episode_batch,
        load_family_grid,
        make_plan,
    )
    from uavsim.data.recipe import parse_recipe

    a = ds.attrs
    try:
        recipe = parse_recipe(a["recipe"], f"{ds.path} (recipe attribute)", ds.path.stem)
        grid = load_family_grid(recipe)
    except UserError as exc:
        return None, f"cannot rebuild the plan: {exc}"
    if (grid.hash or "") != a["grid_hash"]:
        return None, f"the {recipe.loop} grid changed since the file was made (grid hash {a['grid_hash'][:12]} in the " \
                     f"file, {(grid.hash or '')[:12]} now)"
    try:
        plan = make_plan(recipe, grid, a.get("att_class"))
    except UserError as exc:
        return None, f"cannot rebuild the plan: {exc}"
    e = int(ds.episode[row])
    where = [i for i, c in enumerate(plan.chunks) if e in c]
    if e >= plan.n or not where:
        return None, f"episode {e} is not in the recipe's plan"
    ci = where[0]
    ids = plan.chunks[ci]
    checks = {"sim_seed": (plan.sim_seeds[ci], ds.sim_seed[row]), "K": (plan.K[e], ds.K[row]),
              "bias": (plan.bias[e], ds.bias[row]), "y0": (plan.y0[e], ds.y0[row]),
              "label": (plan.labels[e], ds.labels[row])}
    if plan.recipe.test.settings == "fixed":
        checks.update({"tau_obs": (plan.tau_obs[e], ds.tau_obs[row]), "a_n": (plan.a_n[e], ds.a_n[row])})
    if int(a.get("relay_reading", 1)) != READING:
        return None, f"the file was made with relay reading {int(a.get('relay_reading', 1))}, this version runs " \
                     f"reading {READING}"
    for k, v in ds.effects.items():
        if k in plan.effect_params:
            checks[f"effects/{k}"] = (plan.effect_params[k][e], v[row])
    bad = [k for k, (p, f) in checks.items() if not np.isclose(float(p), float(f), rtol=1e-12, atol=0.0)]
    if bad:
        return None, f"the rebuilt plan's draws differ from the file's ({', '.join(bad)})"
    r = plan.recipe
    dur = float(plan.durations[ci])
    lb, ctrl = episode_batch(chunk_params(plan, ids), plan, ids, dur, int(plan.sim_seeds[ci]), chunk=ci,
                             record_state=True)
    relay_first = ctrl.history[0] if isinstance(ctrl, RefiningRelay) else (ctrl.tau_obs.copy(), ctrl.a_n.copy())
    res = lb.run(ctrl, dur)
    j = int(np.flatnonzero(ids == e)[0])
    relay = ctrl.relay if isinstance(ctrl, RefiningRelay) else ctrl
    final = {"tau_obs": (relay.tau_obs[j], ds.tau_obs[row]), "a_n": (relay.a_n[j], ds.a_n[row])}
    bad = [k for k, (p, f) in final.items() if not np.isclose(float(p), float(f), rtol=1e-12, atol=0.0)]
    if bad:
        return None, f"the re-simulated episode's relay settings differ from the file's ({', '.join(bad)})"
    if res.diverged[j]:
        return None, f"the re-simulated episode diverged ({res.reasons.get(j)})"
    X, _, _, _ = preprocess.features_batch(np.nan_to_num(res.y[j:j + 1]), res.u[j:j + 1], r.episodes.rate_hz,
                                           np.full(1, r.test.h), plan.bias[[e]], plan.L, cycles=r.preprocess.cycles)
    # the settings' changes within the episode (recommended settings: the refined runs)
    retunes = []
    if isinstance(ctrl, RefiningRelay):
        retunes = [(int(k), float(tau[j]), float(an[j]))
                   for k, (tau, an) in zip(sorted(ctrl.bounds), ctrl.history[1:], strict=True)]
    return ({"y": res.y[j], "u": res.u[j], "y_true": res.y_true[j], "qpos": res.qpos[j],
             "rotor_force": res.rotor_force[j], "x": X[0], "chunk": ci, "chunk_size": len(ids),
             "first": (float(relay_first[0][j]), float(relay_first[1][j])), "retunes": retunes},
            f"simulated again: chunk {ci} ({len(ids)} episodes, seed {int(plan.sim_seeds[ci])}, {dur:g} s)")


def dataset_runs(path: str | Path, cls: int = 0, episode: int = 0, *, resimulate: bool = True
                 ) -> tuple[list[ReplayRun], dict[str, Any]]:
    """Episode ``episode`` of label ``cls`` of a dataset file, as one ReplayRun.

    Parameters
    ----------
    path : path-like
        A ``uavsim-dataset/1`` file.
    cls : int
        Label (row of the file's class table), 0..n_classes-1.
    episode : int
        Index among the kept episodes of that label, 0..count-1.
    resimulate : bool
        Simulate the episode's chunk again (noise-free output, pose; see module docstring).

    Returns
    -------
    runs : list of one ReplayRun
    info : dict
        ``dataset``, ``loop``, ``control_rate_hz``, ``class``, ``grid_class``,
        ``episode``, ``row`` (in the file), ``plan_episode`` (in the recipe's
        plan), ``resimulated`` (bool), ``raw`` (bool: the file kept raw traces).

    Raises
    ------
    UserError
        Not a dataset, corrupt or incomplete file, class or episode out of range.
    """
    from uavsim.data.h5 import open_dataset

    ds = open_dataset(path)
    row = _pick_row(ds, int(cls), int(episode))
    a = ds.attrs
    rate = float(a["rate_hz"])
    h = float(a["h"])
    label = f"{Path(path).name} class {cls} episode {episode}"
    stem = f"class{cls}_episode{episode}"
    gidx = ds.class_table.get("grid_index")
    grid_class = int(gidx[cls]) if gidx is not None else None
    notes: list[tuple[str, str]] = []
    kind_name = ds.noise_kinds[int(ds.noise_kind[row])]
    desc = (f"{label}: {a['loop']} grid class {grid_class}, K = {ds.K[row]:.4g}, bias = {ds.bias[row]:.4g}, "
            f"noise {kind_name} at {ds.noise_level[row]:.3g} a0, tau_obs = {ds.tau_obs[row]:.4g} s, "
            f"a_n = {ds.a_n[row]:.4g}, period {ds.period[row]:.4g} s, amplitude {ds.amplitude[row]:.4g} "
            f"(plan episode {int(ds.episode[row])}, file row {row})")
    notes.append(("INFO", desc))
    raw = None
    if ds.raw is not None:
        n = int(ds.raw["length"][row])
        raw = {"y": ds.raw["y"][row, :n].astype(np.float64), "u": ds.raw["u"][row, :n].astype(np.float64)}
    sim, why = (None, "re-simulation not asked for")
    if resimulate:
        sim, why = _resimulate_chunk(ds, row)
    if sim is not None:
        dx = float(np.max(np.abs(sim["x"] - ds.inputs[row])))
        ok = dx <= 1e-5
        if raw is not None:
            m = min(raw["y"].size, sim["y"].size)
            dy = float(np.max(np.abs(sim["y"][:m] - raw["y"][:m]))) if m else math.inf
            scale = float(np.ptp(raw["y"][:m])) if m else 1.0
            ok = ok and m == sim["y"].size and dy <= 1e-5 * max(scale, 1e-12)
            why += f"; max |y - raw y| = {dy:.3g}"
        why += f"; max |input - file input| = {dx:.3g}"
        if ok:
            notes.append(("INFO", f"{label}: {why}: reproduces the file exactly (noisy y as the relay saw it, "
                                  f"noise-free y_true, vehicle pose)"))
        else:
            shown = "the file's raw y, u" if raw is not None else "the re-simulated y, u (the file kept no raw traces)"
            notes.append(("WARN", f"{label}: {why}: does NOT reproduce the file; showing {shown}, with the "
                                  f"re-simulation's y_true and pose"))
    else:
        notes.append(("WARN", f"{label}: no exact re-simulation ({why}); replaying what the file holds"))
    exact = sim is not None and notes[-1][0] == "INFO"
    signals: dict[str, np.ndarray] = {}
    if exact:
        y, u = sim["y"], sim["u"]
    elif raw is not None:
        y, u = raw["y"], raw["u"]
    elif sim is not None:
        y, u = sim["y"], sim["u"]
    else:
        # only the network input: the last cycle(s), normalized, at the input rate
        x = ds.inputs[row].astype(np.float64)
        notes.append(("WARN", f"{label}: the file kept no raw traces: y and u are the network input "
                              f"(normalized, {x.shape[1]} samples at {a.get('input_rate_hz', rate)} Hz)"))
        y, u = x[0], x[1]
        rate = float(a.get("input_rate_hz", rate))
    if raw is not None and exact:
        signals["raw_y"] = raw["y"]  # the file's float32 trace, beside the re-simulated one
    T = y.size
    t = np.arange(T) / rate
    relay = {"beta": float(a["beta"]), "h": h, "tau_obs": float(ds.tau_obs[row]), "a_n": float(ds.a_n[row]),
             "bias": float(ds.bias[row]), "reading": int(a.get("relay_reading", 1))}
    if sim is not None and sim["retunes"]:
        # the episode ran its first settings, then each refined run's (see uavsim.data.generate)
        relay["tau_obs"], relay["a_n"] = sim["first"]
        relay["retunes"] = sim["retunes"]
    run = ReplayRun(stem=stem, label=label, kind=NP_MRFT_RUN, t=t, r=np.zeros(T), y=y, u=u, rate_hz=rate,
                    relay=relay if (sim is not None or raw is not None) else None,
                    y_true=sim["y_true"] if sim is not None else None,
                    qpos=sim["qpos"] if sim is not None else None,
                    rotor_force=sim["rotor_force"] if sim is not None else None, signals=signals, notes=notes,
                    info={"file": str(path)})
    if run.relay is None:
        run.kind = "input"
    info = {"dataset": str(path), "loop": a["loop"], "control_rate_hz": float(a["rate_hz"]), "class": int(cls),
            "grid_class": grid_class, "episode": int(episode), "row": row, "plan_episode": int(ds.episode[row]),
            "resimulated": sim is not None, "exact": exact, "raw": raw is not None,
            "raw_length": int(raw["y"].size) if raw is not None else None}
    return [run], info


# -- scenario runs ----------------------------------------------------------------------------------

def scenario_runs(path: str | Path, run: str | None = None) -> tuple[list[ReplayRun], dict[str, Any]]:
    """The episodes of a scenario run (``x.rrd`` with ``x.run.npz`` beside it, the ``.run.npz``, or its folder).

    Parameters
    ----------
    path : path-like
    run : str, optional
        Only this episode (``altitude/relay`` or its stem ``altitude_relay``).

    Returns
    -------
    runs : list of ReplayRun
    info : dict
        ``scenario`` (name), ``run_file``, ``result`` (the run's JSON result).
    """
    from uavsim.scenario.record import read_run, run_path

    p = Path(path)
    if p.is_dir():
        files = sorted(p.glob("*.run.npz"))
        if len(files) != 1:
            raise UserError(f"{p}: expected one scenario run file *.run.npz, found {len(files)}")
        p = files[0]
    elif p.suffix == ".rrd":
        side = run_path(p)
        if not side.exists():
            raise UserError(f"{p}: no scenario run file {side.name} beside it (written by `uavsim scenario run`; "
                            f"run the scenario again to replay it)")
        p = side
    data = read_run(p)
    meta = data["meta"]
    out = []
    for ep in meta["episodes"]:
        name = ep["name"]
        stem = entity_stem(name.replace("/", "_"))
        if run is not None and run not in (name, stem):
            continue
        arr = data["episodes"][name]
        t = arr["t"]
        rate = 1.0 / float(t[1] - t[0]) if t.size > 1 else 200.0
        ctrl = ep.get("controller") or {}
        kind = ctrl.get("kind", "pd")
        relay = None
        if kind in RELAY_KINDS:
            relay = {k: ctrl.get(k) for k in ("beta", "h", "tau_obs", "a_n", "bias")}
            relay["bias"] = relay["bias"] or 0.0
            relay["reading"] = int(ctrl.get("reading", 1))  # runs recorded before reading 2 ran reading 1
        signals = {k: arr[k] for k in ("y_cam", "y_kf", "target", "innovation", "force", "schedule") if k in arr}
        desc = ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}" for k, v in ctrl.items())
        notes = [("INFO", f"{name}: {meta.get('scenario')} scenario episode, {ep.get('loop')} loop, {desc}")]
        if ep.get("diverged"):
            notes.append(("WARN", f"{name}: the episode diverged (NaN rows are not logged)"))
        out.append(ReplayRun(stem=stem, label=name, kind=kind, t=t, r=arr["r"], y=arr["y"], u=arr["u"],
                             rate_hz=rate, relay=relay, y_true=arr.get("y_true"), qpos=arr.get("qpos"),
                             rotor_force=arr.get("rotor_force"), signals=signals, notes=notes,
                             info={"file": name}))
    if not out:
        names = ", ".join(ep["name"] for ep in meta["episodes"])
        raise UserError(f"scenario run {p}: no episode {run!r} (episodes: {names})")
    return out, {"scenario": meta.get("scenario"), "run_file": str(p), "result": meta.get("result")}
