"""Simulate the runs of a session on the MuJoCo loop, with the session's controller semantics.

Every run of a session (np-mrft, mrft, step) is re-played in closed loop on
:class:`~uavsim.sim.runner.LoopBatch` with the run's own controller
parameters (``NPMRFT`` / ``MRFT`` / ``PD`` of ``uavsim.control``, the
normative semantics of ``session.md``) and the model's measurement noise. One
call simulates many *episodes* at once: each is one run under one candidate
effect at one parameter value with one noise seed, so that a whole fitting
grid is one batch.

    plans = [Episode(run=0), Episode(run=1, effect="delay", value=0.02)]
    sims = simulate(session, model, plans, seed=3)
    sims[1].y      # (T_run,) the measurement the controller saw, for run 1 with the extra delay
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uavsim.control.pd import PD
from uavsim.control.relay import NPMRFT
from uavsim.errors import UserError
from uavsim.formats.session import ModelSpec, Run, Session
from uavsim.gap.vector_effects import batch_effects
from uavsim.lumped.params import LumpedParams
from uavsim.sim.runner import LoopBatch

__all__ = ["Episode", "SimRun", "simulate", "SUPPORTED_LOOPS"]

SUPPORTED_LOOPS = ("altitude", "roll", "pitch")


@dataclass(frozen=True)
class Episode:
    """One simulated episode: run ``run`` of the session under ``effect`` = ``value``.

    Attributes
    ----------
    run : int
        Index into ``session.runs``.
    effect : str
        Vocabulary name, ``"none"`` for the bare model.
    value : float
        The effect's parameter (vocabulary units).
    seed : int
        Index of the noise realization (episodes with equal seeds still draw
        different numbers: one generator feeds the whole batch).
    """

    run: int
    effect: str = "none"
    value: float = 0.0
    seed: int = 0


@dataclass
class SimRun:
    """The simulated samples of one episode, trimmed to its run's length.

    Attributes
    ----------
    t, r, y, u : ndarray (T_run,)
        As the run CSV columns; NaN everywhere when the episode diverged.
    diverged : bool
    """

    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    diverged: bool


class _Mixed:
    """Relay episodes and PD episodes of one batch, selected per episode (``e`` (n,) -> ``u`` (n,))."""

    def __init__(self, runs: Sequence[Run], plans: Sequence[Episode], rate_hz: float):
        n = len(plans)
        specs = [runs[p.run].spec for p in plans]
        self.is_step = np.array([s.kind == "step" for s in specs])
        f = lambda name, default: np.array(  # noqa: E731
            [default if getattr(s, name) is None else float(getattr(s, name)) for s in specs]
        )
        relay = ~self.is_step
        self.relay = None
        if relay.any():
            beta = np.where(relay, f("beta", -0.5), -0.5)
            h = np.where(relay, f("h", 1.0), 1.0)
            self.relay = NPMRFT(beta, h, f("tau_obs", 0.0), f("a_n", 0.0), rate_hz, n, bias=f("bias", 0.0))
            # mrft: an extremum is confirmed one sample after it was set (session.md)
            self.relay.n_obs[np.array([s.kind == "mrft" for s in specs])] = 1
        self.pd = None
        if self.is_step.any():
            self.pd = PD(f("kp", 0.0), f("kd", 0.0), f("derivative_filter_hz", 1.0), rate_hz, n)

    def __call__(self, e: np.ndarray) -> np.ndarray:
        if self.relay is None:
            return self.pd(e)
        ur = self.relay(e)
        if self.pd is None:
            return ur
        return np.where(self.is_step, self.pd(e), ur)


def model_params(session: Session, model: ModelSpec) -> LumpedParams:
    """The session's loop with the model's lumped parameters (checked)."""
    if session.loop not in SUPPORTED_LOOPS:
        raise UserError(
            f"loop {session.loop!r}: the gap workflow supports {', '.join(SUPPORTED_LOOPS)} "
            "(lateral loops are not fidelity-tested yet)"
        )
    return LumpedParams(session.loop, K=model.K, T_prop=model.T_prop, T1=model.T1, tau=model.tau).check()


def _reference(run: Run, T: int, rate_hz: float) -> np.ndarray:
    s = run.spec
    t = np.arange(T) / rate_hz
    if s.kind == "step":
        return np.where(t >= float(s.step_time), float(s.step), 0.0)
    r = np.asarray(run.data.r, dtype=np.float64)
    return np.concatenate([r, np.full(max(T - r.size, 0), r[-1])])[:T]


def simulate(
    session: Session,
    model: ModelSpec,
    plans: Sequence[Episode],
    seed: int = 0,
    nthread: int = 0,
    dt: float = 0.0005,
    base_effects: dict[str, float] | None = None,
) -> list[SimRun]:
    """Simulate the episodes ``plans`` of ``session`` under ``model`` in one MuJoCo batch.

    Parameters
    ----------
    session : Session
        Gives the loop, the control rate and the runs (controller, length, reference).
    model : ModelSpec
        Lumped parameters and measurement noise std (output units).
    plans : sequence of Episode, length n
    seed : int
        Seed of the batch's random draws (noise).
    nthread : int
        MuJoCo threads (0: all CPUs).
    dt : float
        Physics step, s.
    base_effects : dict of str to float, optional
        Effects on every episode (the session's ``[[effects]]``), name -> its one parameter.

    Returns
    -------
    list of SimRun, length n
    """
    rate = float(session.control_rate_hz)
    p = model_params(session, model)
    lens = [session.runs[e.run].data.t.size for e in plans]
    T = max(lens)
    names = [e.effect for e in plans]
    values = [e.value for e in plans]
    fx = batch_effects(names, values, float(model.noise_std), rate, base=base_effects)
    lb = LoopBatch([p] * len(plans), dt=dt, rate_hz=rate, effects=fx, seed=seed, nthread=nthread)
    ref = np.stack([_reference(session.runs[e.run], T, rate) for e in plans])
    res = lb.run(_Mixed(session.runs, plans, rate), T / rate, reference=ref)
    out = []
    for i, L in enumerate(lens):
        out.append(SimRun(res.t[:L], res.r[i, :L], res.y[i, :L], res.u[i, :L], bool(res.diverged[i])))
    return out
