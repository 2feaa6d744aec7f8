"""The Python API: what the ``uavsim`` commands do, as functions of ``import uavsim``.

Each function takes paths or plain values, returns plain data (dicts of floats,
the JSON the matching command prints with ``--json``) or the project's result
objects (no function shares a name with a subpackage: ``uavsim.gap`` is the package,
``uavsim.find_gap`` the function), and raises ``uavsim.UserError`` (one line) on bad input. ``import
uavsim`` stays light: each function imports what it needs when called, and
identification needs neither torch nor the training code.

    import uavsim
    s = uavsim.import_log("flight.ulg", "flights/alt", preset="px4-altitude", beta=-0.73,
                          tau_obs=0.02, a_n=0.002)
    ans = uavsim.identify_session("flights/alt", models="training/runs")
    ans["params"], ans["gains"]
    uavsim.plot_identification("flights/alt", ans, "alt.png")
    uavsim.export_gains(ans, "px4", "alt.params", hover_thrust=0.42)
"""

from __future__ import annotations

import os
from typing import Any

__all__ = ["identify_session", "plot_identification", "tune", "generate", "train", "find_gap", "import_log",
           "export_gains", "read_session", "write_session", "json_schema"]

PathLike = str | os.PathLike


def identify_session(session: PathLike, models: PathLike | None = None, *, run: str | None = None,
                     attitude_class: int | None = None, optimum: str = "never",
                     second_run: str | None = "auto") -> dict[str, Any]:
    """Identify a loop from a session's relay run (DNN-NP-MRFT), without torch.

    Parameters
    ----------
    session : path-like
        Session folder (or its ``session.toml``) with an ``np-mrft`` or ``mrft`` run.
    models : path-like, optional
        Exported network folder, or a root with ``altitude/``, ``attitude/`` (default
        ``$UAVSIM_MODELS`` or ``training/runs`` under the current directory).
    run : str, optional
        CSV file name of the run to use (default: the first np-mrft run).
    attitude_class : int, optional
        Lateral sessions: the attitude class of the roll/pitch loop underneath.
    optimum : ``"never"``, ``"auto"`` or ``"always"``
        Also compute the identified model's own optimum at the control rate (~10-20 ms) and answer
        it when the model is off the grid (``auto``) or always; default: the table's answer only.
    second_run : str, optional
        CSV file name of a second relay run at another beta whose measured point weighs the belief;
        ``"auto"`` (default): the session's run at beta -0.3 where it holds one; None: the first run
        alone. On lateral sessions it also pins the family of models the first point allows, and
        answers alone where the first run is refused (``uavsim.ident.family``).

    Returns
    -------
    dict
        ``uavsim identify --json``: ``loop``, ``class``, ``params`` (K, T_prop, T1, tau in s),
        ``gains`` (kp, kd, derivative_filter_hz in session units), ``gains_source``, ``table``,
        ``oscillation``, ``response``, ...
    """
    from uavsim.ident.session import identify_session as _identify

    return _identify(session, models=models, run=run, attitude_class=attitude_class, optimum=optimum,
                     second_run=second_run)


def plot_identification(session: PathLike, answer: dict[str, Any], png: PathLike) -> str:
    """Write the identification picture (``uavsim identify --plot``): measured vs model cycle, Nyquist point.

    Returns the PNG's path.
    """
    from uavsim.learning.figures import identification_png

    return str(identification_png(session, answer, png))


def tune(loop: str, *, T_prop: float, T1: float, tau: float, K: float = 1.0, beta: float | None = None,
         pm_deg: float | None = None) -> dict[str, float]:
    """PD gains of the MRFT tuning rule for an inner-loop lumped process ``K e^{-tau s} / (s (T_prop s + 1)(T1 s + 1))``.

    Parameters
    ----------
    loop : ``"altitude"``, ``"roll"`` or ``"pitch"``
    T_prop, T1, tau : float
        Time constants and delay, s.
    K : float
        Loop gain, output units per command unit per s (the gains scale as 1/K).
    beta, pm_deg : float, optional
        The rule's MRFT parameter and phase margin (deg); default the grids' rule.

    Returns
    -------
    dict
        ``kp``, ``kd``, ``derivative_filter_hz``, ``omega`` (rad/s), ``beta``, ``pm_deg``.
    """
    from uavsim.errors import UserError
    from uavsim.lumped.params import LumpedParams, loop_family
    from uavsim.tuning.rule import DEFAULT_BETA, DEFAULT_PM_DEG, TuningRule

    if loop_family(loop) == "lateral":
        raise UserError("uavsim.tune takes inner loops; lateral loops: `uavsim tune --loop lateral_y ...`")
    g = TuningRule(DEFAULT_BETA if beta is None else beta, DEFAULT_PM_DEG if pm_deg is None else pm_deg).gains(
        LumpedParams(loop, K, T_prop, T1, tau))
    return {"kp": g.kp, "kd": g.kd, "derivative_filter_hz": g.derivative_filter_hz, "omega": g.omega,
            "beta": g.beta, "pm_deg": g.pm_deg}


def generate(recipe: PathLike, out: PathLike | None = None, *, backend: str = "threads", progress: bool = False
             ) -> dict[str, Any]:
    """Generate the training set of a dataset recipe (``uavsim generate``).

    Parameters
    ----------
    recipe : path-like
        Dataset recipe TOML (``datasets/*.toml``), validated by ``uavsim.schema``.
    out : path-like, optional
        HDF5 file (default: the recipe's path with ``.h5``).
    backend : ``"threads"``, ``"dask:local:N"`` or ``"dask:ADDRESS"``
    progress : print progress on stderr

    Returns
    -------
    dict
        ``files``, ``n_episodes``, ``n_kept``, ``wall_s``, ...
    """
    from uavsim.data.generate import generate as _generate
    from uavsim.data.recipe import load_recipe

    return _generate(load_recipe(recipe), out, backend=backend, progress=progress)


def train(recipe: PathLike, *, resume: bool = False, quiet: bool = True) -> list[dict[str, Any]]:
    """Train the network(s) of a training recipe (``uavsim train``; needs ``uavsim[train]``).

    Returns one report per network (``out``: the exported folder with ``weights.npz``,
    ``model.onnx``, ``model.pt``, ``meta.json`` and ``training.png``).
    """
    from uavsim.learning.train import train_from_recipe

    return train_from_recipe(recipe, resume=resume, quiet=quiet)


def find_gap(session: PathLike, *, model: PathLike | None = None, seed: int = 0) -> dict[str, Any]:
    """Which physical effect the session's model lacks (``uavsim gap --json``).

    Parameters
    ----------
    session : path-like
        Session with a ``[model]`` (or give ``model``) and relay or step runs.
    model : path-like, optional
        TOML with a ``[model]`` table to test instead of the session's.
    seed : int
        Seed of the simulated noise.

    Returns
    -------
    dict
        ``effect``, ``params``, ``gap_before``, ``gap_after``, ``ranking``, ...
    """
    from uavsim.formats.session import read_session as _read
    from uavsim.gap.workflow import read_model_file, run_gap

    s = _read(session)
    m = read_model_file(model, s.loop) if model is not None else None
    return run_gap(s, model=m, seed=seed).to_json()


def import_log(log: PathLike, out: PathLike, **kw: Any) -> dict[str, Any]:
    """A flight log (PX4 ULog, ArduPilot DataFlash, ROS 2 bag) as a session (``uavsim session import``).

    Keyword arguments are those of ``uavsim.logs.import_log`` (``preset``, ``r``, ``y``, ``u``,
    ``loop``, ``kind``, ``beta``, ``h``, ``bias``, ``tau_obs``, ``a_n``, ``rate_hz``, ``start``, ``stop``,
    ``bias_trim``).
    Returns what was written and what was detected.
    """
    from uavsim.logs import import_log as _import

    return _import(log, out, **kw)


def export_gains(answer: dict[str, Any], autopilot: str, out: PathLike, *, cmd_scale: float | None = None,
                 hover_thrust: float | None = None) -> dict[str, float]:
    """Write identified gains as a PX4 ``.params`` or ArduPilot ``.parm`` file (``uavsim export-gains``).

    Parameters
    ----------
    answer : dict
        ``identify_session``'s answer.
    autopilot : ``"px4"`` or ``"ardupilot"``
    out : path-like
        The parameter file.
    cmd_scale, hover_thrust : float
        The vehicle's autopilot units per session command unit, or (altitude, u normalized
        thrust) the hover thrust; see ``uavsim.autopilot.params``.

    Returns
    -------
    dict
        Parameter name -> value, as written.
    """
    from uavsim.autopilot import export_gains as _export
    from uavsim.autopilot import write_params

    exp = _export(answer, autopilot, cmd_scale=cmd_scale, hover_thrust=hover_thrust)
    write_params(exp, out)
    return exp.as_dict()


def read_session(path: PathLike):
    """Read and check a session folder (``uavsim.formats.session.read_session``)."""
    from uavsim.formats.session import read_session as _read

    return _read(path)


def write_session(session, path: PathLike):
    """Check and write a session folder atomically (``uavsim.formats.session.write_session``)."""
    from uavsim.formats.session import write_session as _write

    return _write(session, path)


def json_schema(kind: str) -> dict[str, Any]:
    """The JSON Schema of a TOML file kind: session, dataset, training, scenario, gap-model
    (``uavsim schema KIND``; the ``uavsim.schema`` package holds the schemas themselves)."""
    from uavsim.schema import json_schema as _schema

    return _schema(kind)
