"""The episodes of a plan on the MuJoCo loop: effects, relay, batch, preprocessing.

A chunk of a plan is one ``LoopBatch`` with the plan's noise and effects and
NP-MRFT closing the loop (recommended settings refined stage by stage:
:class:`RefiningRelay`); its result is a pure function of the plan and the
chunk's index (:func:`run_chunk`), which is what makes generation resumable
and backend-independent. Replays build the same batch (:func:`episode_batch`).

    res = run_chunk(plan, 0)
    res["X"].shape      # (m, C, L) network inputs of the chunk's episodes
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np

from uavsim.control.relay import NPMRFT, relay_command
from uavsim.data import preprocess
from uavsim.data.noise_trace import NoiseTrace
from uavsim.data.plan import HOVER_S, STAGE_SETTLE, Plan, load_family_grid, make_plan
from uavsim.data.recipe import parse_recipe
from uavsim.lumped.params import LumpedParams
from uavsim.model.effects import make_effect
from uavsim.noise.estimate import (
    estimate_noise_batch,
    recommend,
    refine_batch,
    synthetic_hover,
)
from uavsim.noise.models import make_noise
from uavsim.sim.runner import LoopBatch


def _noise_effect(kinds: tuple[str, ...], kind: np.ndarray, amp: np.ndarray, samples: int) -> NoiseTrace | None:
    # precomputed for the whole episode: per-sample study models cost as much Python
    # time as the rest of the loop (uavsim.data.noise_trace)
    groups = []
    for k, name in enumerate(kinds):
        idx = np.flatnonzero((kind == k) & (amp > 0))
        if name == "none" or not len(idx):
            continue
        groups.append((idx, make_noise(name, 1.0, amp[idx])))
    return NoiseTrace(groups=groups, samples=samples) if groups else None


def episode_effects(plan: Plan, ids: np.ndarray, samples: int) -> list:
    r = plan.recipe
    fx = []
    noise = _noise_effect(r.noise.kinds, plan.noise_kind[ids], plan.noise_level[ids] * plan.a0[ids], samples)
    if noise is not None:
        fx.append(noise)  # the noise is what the sensor adds; recipe sensor effects act on the noisy value
    for i, spec in enumerate(r.effects):
        params = {k: (plan.effect_params[f"{i}_{spec.name}/{k}"][ids] if isinstance(v, tuple) else v)
                  for k, v in spec.params.items()}
        fx.append(make_effect(spec.name, **params))
    return fx


class RefiningRelay:
    """NP-MRFT re-tuned ``refinements`` times, every ``stage`` samples, from the stage just run.

    A user's successive relay runs (:func:`uavsim.noise.estimate.refine` on each run
    for the next) within one episode, without their start transients: at samples
    ``stage, 2 stage, ...`` the settings are refined (``refine_batch``) from the
    stage's errors and outputs after its first ``STAGE_SETTLE`` and applied from
    that sample on (``NPMRFT.retune``). Called like the relay, ``e`` (n,) -> ``u`` (n,).

    Attributes
    ----------
    relay : NPMRFT
    history : list of (tau_obs, a_n) arrays (n,), the settings of each stage
    """

    def __init__(self, relay: NPMRFT, stage: int, refinements: int, hover_a_n: np.ndarray):
        self.relay = relay
        self.stage = int(stage)
        self.bounds = {self.stage * (i + 1) for i in range(refinements)} if self.stage > 0 else set()
        T = max(self.bounds, default=0)
        # the stages' errors and commands, sample-major (one contiguous row per sample)
        self.E = np.empty((T, relay.n))
        self.U = np.empty((T, relay.n))
        self.hover_a_n = np.asarray(hover_a_n, dtype=np.float64)
        self.history = [(relay.tau_obs.copy(), relay.a_n.copy())]
        self.k = 0

    @property
    def switched(self) -> np.ndarray:
        return self.relay.switched

    def __call__(self, e: np.ndarray) -> np.ndarray:
        k = self.k
        if k in self.bounds:
            r = self.relay
            a = k - self.stage
            t = np.arange(self.stage) / r.rate_hz
            E, U = (np.ascontiguousarray(x[a:k].T) for x in (self.E, self.U))  # (n, stage)
            rf = refine_batch(t, np.nan_to_num(E), U, beta=r.beta, tau_obs=r.tau_obs,
                              a_n=r.a_n, rate_hz=r.rate_hz, settle=STAGE_SETTLE * self.stage / r.rate_hz,
                              hover_a_n=self.hover_a_n)
            r.retune(rf["tau_obs"], rf["a_n"])
            self.history.append((r.tau_obs.copy(), r.a_n.copy()))
        u = self.relay(e)
        if k < len(self.E):
            self.E[k] = e
            self.U[k] = u
        self.k += 1
        return u


def episode_controller(plan: Plan, ids: np.ndarray, chunk: int, seed: int) -> NPMRFT | RefiningRelay:
    """The NP-MRFT of episodes ``ids`` (chunk ``chunk``, simulation seed ``seed``).

    Fixed settings: the plan's. Recommended settings: each episode's hover
    segment (``HOVER_S`` of its own noise, drawn from ``SeedSequence([seed, 1])``)
    gives its first run's settings (``estimate_noise``, ``recommend``), refined in
    the episode by :class:`RefiningRelay` every ``plan.stage_s[chunk]``.
    """
    r = plan.recipe
    rate = r.episodes.rate_hz
    m = len(ids)
    if r.test.settings == "fixed":
        return NPMRFT(plan.beta, r.test.h, plan.tau_obs[ids], plan.a_n[ids], rate, m, bias=plan.bias[ids],
                      bias_trim=r.test.bias_trim)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 1]))
    steps = int(round(HOVER_S * rate))
    eff = _noise_effect(r.noise.kinds, plan.noise_kind[ids], plan.noise_level[ids] * plan.a0[ids], steps)
    hover = synthetic_hover(m, HOVER_S, rate, plan.a0[ids], eff, rng)
    tau, a_n, q = np.empty(m), np.empty(m), np.empty(m)
    for i, est in enumerate(estimate_noise_batch(hover, rate)):
        tau[i], a_n[i] = recommend(est, plan.beta)
        q[i] = est.a_n
    relay = NPMRFT(plan.beta, r.test.h, tau, a_n, rate, m, bias=plan.bias[ids], bias_trim=r.test.bias_trim)
    stage = int(round(float(plan.stage_s[chunk]) * rate))
    return RefiningRelay(relay, stage, r.test.refinements, q)


def chunk_params(plan: Plan, ids: np.ndarray) -> list[LumpedParams]:
    """The processes of episodes ``ids`` of ``plan``: their class's lumped parameters at their drawn gain
    (an off-grid plan: the episode's own time constants, ``plan.process``)."""
    out = [replace(plan.grid.params_of(int(plan.class_index[plan.labels[e]])), K=float(plan.K[e])) for e in ids]
    if plan.process is not None:
        out = [replace(p, **{k: float(v[e]) for k, v in plan.process.items()}) for p, e in zip(out, ids, strict=True)]
    return out


def episode_batch(params: list[LumpedParams], plan: Plan, ids: np.ndarray, duration_s: float, seed: int, *,
                  nthread: int = 0, chunk: int = 0, record_state: bool = False
                  ) -> tuple[LoopBatch, NPMRFT | RefiningRelay]:
    """The batch and the controller that fly episodes ``ids`` (of chunk ``chunk``) of ``plan``.

    Generation runs them; a replay runs them again with ``record_state=True`` (same draws).
    """
    r = plan.recipe
    samples = int(round(duration_s * r.episodes.rate_hz))
    lb = LoopBatch(params, dt=r.episodes.dt, rate_hz=r.episodes.rate_hz, effects=episode_effects(plan, ids, samples), seed=seed,
                   nthread=nthread, y0=plan.y0[ids], record_state=record_state)
    return lb, episode_controller(plan, ids, chunk, seed)


def run_episodes(params: list[LumpedParams], plan: Plan, ids: np.ndarray, duration_s: float, seed: int,
                 nthread: int = 0, chunk: int = 0) -> dict[str, np.ndarray]:
    """Simulate episodes ``ids`` (of chunk ``chunk``) of ``plan`` with the processes ``params`` and preprocess them.

    Returns
    -------
    dict with ``ids`` (m,), ``X`` (m, C, L) float32, ``period``, ``amplitude``, ``response``
    (complex), ``response_period`` (m,) (``preprocess.CycleFeatures``),
    ``ok``, ``diverged`` (m,) bool, ``tau_obs``, ``a_n`` (m,) the NP-MRFT settings of the
    episode proper, ``duration_s`` scalar, and ``y``, ``u`` (m, T) float32 when the recipe
    keeps raw traces.
    """
    r = plan.recipe
    m = len(ids)
    lb, ctrl = episode_batch(params, plan, ids, duration_s, seed, nthread=nthread, chunk=chunk)
    res = lb.run(ctrl, duration_s)
    relay = ctrl.relay if isinstance(ctrl, RefiningRelay) else ctrl
    resp: dict[str, np.ndarray] = {}
    u = relay_command(res.u, r.test.h, plan.bias[ids], r.test.bias_trim)
    X, period, amp, ok = preprocess.features_batch(
        np.nan_to_num(res.y), u, r.episodes.rate_hz, np.full(m, r.test.h), plan.bias[ids], plan.L,
        cycles=r.preprocess.cycles, response=resp)
    ok &= ~res.diverged
    out = {"ids": np.asarray(ids, dtype=np.int64), "X": X, "period": period, "amplitude": amp, "ok": ok,
           "diverged": res.diverged.copy(), "tau_obs": relay.tau_obs.copy(), "a_n": relay.a_n.copy(),
           "duration_s": np.float64(duration_s), **resp}
    if r.preprocess.keep_raw:
        out["y"] = res.y.astype(np.float32)
        out["u"] = res.u.astype(np.float32)
    return out


def run_chunk(plan: Plan, index: int, nthread: int = 0) -> dict[str, np.ndarray]:
    """Simulate and preprocess chunk ``index`` of ``plan`` (a pure function of the plan and index)."""
    ids = plan.chunks[index]
    params = chunk_params(plan, ids)
    return run_episodes(params, plan, ids, float(plan.durations[index]), int(plan.sim_seeds[index]), nthread, index)


@functools.lru_cache(maxsize=4)
def _cached_plan(text: str, source: str, name: str, att_class: int | None) -> Plan:
    recipe = parse_recipe(text, source, name)
    return make_plan(recipe, load_family_grid(recipe), att_class)


def chunk_task(text: str, source: str, name: str, att_class: int | None, index: int) -> dict[str, np.ndarray]:
    """Dask task: one chunk, from the recipe text (workers rebuild and cache the plan)."""
    return run_chunk(_cached_plan(text, source, name, att_class), index, nthread=1)
