"""Training-set generation: NP-MRFT episodes in MuJoCo, preprocessed into network inputs.

For every class of a grid (or a subset), ``episodes.per_class`` episodes are
simulated with ``LoopBatch`` with NP-MRFT closing the loop and the noise in the
measurement chain, as in flight; each episode's last cycle(s) go through
``uavsim.data.preprocess`` (the same code identification uses) and the inputs,
labels and draws are written to one ``uavsim-dataset/1`` file (``uavsim.data.h5``).

How it is made reproducible and resumable:

* **Plan.** All per-episode draws (gain factor, relay bias, noise kind and
  level, initial output, randomized effect parameters) come from one
  ``np.random.default_rng(recipe.seed)`` in a fixed order, before anything runs,
  and are stored in the file.
* **Relay settings.** With ``settings = "recommended"`` (the default) each
  episode's NP-MRFT ``tau_obs`` and ``a_n`` are the ones a user gets from the
  same path (``uavsim.noise.estimate``): a hover segment of the episode's own
  noise gives the first run's settings (``recommend``); the episode then runs
  ``refinements`` stages of ``refine_cycles`` cycles, each ending with the
  settings refined from the stage's samples (``refine_batch``,
  :class:`RefiningRelay`), before the episode proper. The final settings are
  what the file stores per episode. ``settings = "fixed"`` keeps the recipe's
  ``tau_obs`` (capped per class) and ``a_n`` (times the noise amplitude).
* **Chunks.** Episodes are sorted by class period and cut into chunks of
  ``episodes.chunk``; a chunk is one ``LoopBatch`` whose episode length follows
  its slowest class (``episodes.cycles``), so fast classes do not pay for
  slow ones. Chunk ``i`` is simulated with seed ``SeedSequence([seed, i])``
  (noise realizations), stored per episode as ``sim_seed``. A chunk's result
  depends only on the recipe and its index, never on the backend, the thread
  count or the order chunks run in.
* **Resume.** Each finished chunk is saved atomically under ``OUT.resume/``;
  an interrupted run (Ctrl-C, kill) is continued by running it again, and the
  file is assembled from the chunks in plan order at the end, so it has the
  same bytes as an uninterrupted run.
* **Backends.** ``threads`` (default): chunks on a local thread pool of 2,
  longest first, each ``LoopBatch`` on all CPUs (the numpy controller of one
  chunk overlaps the physics of another, and the last chunk uses every core). ``dask``: chunks are Dask distributed
  tasks (``local:N`` starts a LocalCluster of N one-thread workers, or a
  scheduler address); a lost worker's tasks are re-run by Dask, and as they are
  pure, the file is the same.

    from uavsim.data.recipe import load_recipe
    from uavsim.data.generate import generate
    summary = generate(load_recipe("datasets/small.toml"), "datasets/small.h5")
    summary["files"], summary["episodes_per_s"]
"""

from __future__ import annotations

import concurrent.futures as cf
import functools
import json
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.control.relay import NPMRFT, READING
from uavsim.data import preprocess
from uavsim.data.h5 import CLASS_FIELDS, CLASS_PARAMS, FORMAT, write_dataset
from uavsim.data.noise_trace import NoiseTrace
from uavsim.data.recipe import Recipe, parse_recipe
from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams
from uavsim.model.effects import make_effect
from uavsim.noise.estimate import (
    estimate_noise_batch,
    recommend,
    refine_batch,
    synthetic_hover,
    tau_obs_max,
)
from uavsim.noise.models import make_noise
from uavsim.sim.runner import LoopBatch

#: extra length over ``cycles`` slowest-class periods: noise and NP-MRFT lengthen cycles
_CYCLE_MARGIN = 1.15
#: s: the hover segment whose noise estimate gives a recommended episode its first settings
HOVER_S = 10.0
#: of a refinement stage: the transient skipped before its samples are analysed
STAGE_SETTLE = 0.25


@dataclass
class Plan:
    """Every episode of one dataset file, drawn before anything runs.

    Per-episode arrays have shape (n,): first the ``n_train`` training episodes in
    class-major order (episode ``e`` is episode ``e % per_class`` of label
    ``e // per_class``), then one reference episode per class (K = 1, no bias, no
    noise, mid-range effects) whose cycle goes to the class table as the cycle at
    this control rate (``period_sim``, ``amplitude_sim``). ``tau_obs`` and ``a_n`` are
    NaN with recommended settings (each episode finds its own, see :func:`episode_controller`);
    ``stage_s`` is the length of each refinement stage of a chunk (0 with fixed settings).
    """

    recipe: Recipe
    grid: Any  # uavsim.tuning.grid.Grid (a lateral sub-grid for lateral files)
    att_class: int | None
    class_index: np.ndarray  # (n_classes,) grid class of each label
    beta: float
    L: int
    labels: np.ndarray
    K: np.ndarray
    bias: np.ndarray
    noise_kind: np.ndarray  # int8, index into RECIPE_NOISE_KINDS order of recipe.noise.kinds
    noise_level: np.ndarray
    y0: np.ndarray
    tau_obs: np.ndarray
    a_n: np.ndarray
    a0: np.ndarray  # expected amplitude, output units (grid amplitude * K * h)
    effect_params: dict[str, np.ndarray]  # "<i>_<name>/<param>" -> (n,) randomized values
    chunks: list[np.ndarray]  # episode ids of each chunk
    durations: np.ndarray  # (n_chunks,) s
    sim_seeds: np.ndarray  # (n_chunks,) uint32
    n_train: int = 0
    stage_s: np.ndarray | None = None  # (n_chunks,) s, refinement stage length (recommended settings)

    @property
    def n(self) -> int:
        return len(self.labels)


def chunk_seed(seed: int, index: int, att_class: int | None = None) -> int:
    """Seed of chunk ``index``'s LoopBatch (noise realizations), from the recipe seed."""
    entropy = [seed, index] if att_class is None else [seed, att_class, index]
    return int(np.random.SeedSequence(entropy).generate_state(1)[0])


def load_family_grid(recipe: Recipe):
    """The recipe's grid (a UserError naming the missing file when it is not built)."""
    from uavsim.tuning.grid import load_grid

    return load_grid(recipe.loop)


def _sub_grid(recipe: Recipe, grid, att_class: int | None):
    if recipe.loop == "lateral":
        if att_class is None:
            raise UserError("a lateral plan needs an attitude class")
        return grid.lateral(att_class)
    return grid


def att_classes_of(recipe: Recipe, grid) -> list[int | None]:
    """The attitude classes a lateral recipe makes files for ([None] for other loops)."""
    if recipe.loop != "lateral":
        return [None]
    n_att = len(grid.sub)
    chosen = list(recipe.att_classes) if recipe.att_classes is not None else list(range(n_att))
    for a in chosen:
        if not 0 <= a < n_att:
            raise UserError(f"{recipe.source}: attitude class {a} out of range 0..{n_att - 1}")
    return chosen


def make_plan(recipe: Recipe, grid, att_class: int | None = None) -> Plan:
    """Draw every episode of the recipe (see module docstring); pure function of its inputs."""
    g = _sub_grid(recipe, grid, att_class)
    if recipe.classes is not None:
        bad = [c for c in recipe.classes if not 0 <= c < g.n]
        if bad:
            raise UserError(f"{recipe.source}: classes {bad} out of range 0..{g.n - 1}")
        class_index = np.asarray(recipe.classes, dtype=np.int64)
    else:
        class_index = np.arange(g.n, dtype=np.int64)
    beta = recipe.test.beta if recipe.test.beta is not None else float(g.beta)
    E, h = recipe.episodes, recipe.test.h
    nc = len(class_index)
    labels = np.repeat(np.arange(nc, dtype=np.int32), E.per_class)
    n = len(labels)
    rng = np.random.default_rng(recipe.seed if att_class is None else [recipe.seed, att_class])
    lo, hi = recipe.randomize.K
    K = np.exp(rng.uniform(math.log(lo), math.log(hi), n))
    bias = rng.uniform(-recipe.randomize.bias, recipe.randomize.bias, n) * h
    w = np.asarray(recipe.noise.weights, dtype=float)
    kind = rng.choice(len(w), size=n, p=w / w.sum()).astype(np.int8)
    level = rng.uniform(*recipe.noise.level, n)
    none = np.array([recipe.noise.kinds[k] == "none" for k in kind], dtype=bool)
    level[none] = 0.0
    y0u = rng.uniform(-1.0, 1.0, n)
    effect_params: dict[str, np.ndarray] = {}
    for i, fx in enumerate(recipe.effects):
        for k, v in fx.params.items():
            if isinstance(v, tuple):
                effect_params[f"{i}_{fx.name}/{k}"] = rng.uniform(v[0], v[1], n)
    cls = class_index[labels]
    a0 = np.asarray(g.amplitude, dtype=float)[cls] * K * h
    y0 = y0u * recipe.randomize.y0 * a0
    period = np.asarray(g.period, dtype=float)
    fixed = recipe.test.settings == "fixed"
    # fixed settings: tau_obs no longer than beta allows for the expected cycle ...
    cap = np.array([tau_obs_max(beta, float(period[c]), E.rate_hz) for c in class_index])
    # ... but at least one sample: with tau_obs = 0 a just-set extremum confirms itself and
    # the relay chatters (plain MRFT confirms one sample later too)
    cls_tau = np.maximum(np.minimum(recipe.test.tau_obs, cap), 1.0 / E.rate_hz) if fixed else np.full(nc, np.nan)
    tau_obs = cls_tau[labels]
    a_n = recipe.test.a_n * level * a0 if fixed else np.full(n, np.nan)
    # Reference episodes, one per class, after the training ones: the class at K = 1 with no
    # bias and no noise. The grid's period and amplitude are the continuous-time cycle; at
    # 200 Hz sampling lengthens the fastest classes' cycles by up to ~25% and their amplitude
    # by up to ~65%, so gain recovery (K_hat = amplitude / h / class amplitude) needs the
    # cycle as simulated at the data's control rate.
    ref = np.arange(nc, dtype=np.int32)
    labels = np.concatenate([labels, ref])
    K = np.concatenate([K, np.ones(nc)])
    bias, level, y0 = (np.concatenate([v, np.zeros(nc)]) for v in (bias, level, y0))
    a_n = np.concatenate([a_n, np.zeros(nc) if fixed else np.full(nc, np.nan)])
    kind = np.concatenate([kind, np.zeros(nc, np.int8)])
    tau_obs = np.concatenate([tau_obs, cls_tau])
    for i, fx in enumerate(recipe.effects):
        for k, v in fx.params.items():
            if isinstance(v, tuple):
                key = f"{i}_{fx.name}/{k}"
                effect_params[key] = np.concatenate([effect_params[key], np.full(nc, 0.5 * (v[0] + v[1]))])
    cls = class_index[labels]
    a0 = np.asarray(g.amplitude, dtype=float)[cls] * K * h
    # chunks: episodes by class period (stable), so a chunk's length follows similar classes
    chunks = []
    for lo_id, hi_id in ((0, n), (n, n + nc)):
        order = lo_id + np.argsort(period[cls[lo_id:hi_id]], kind="stable")
        chunks += [np.sort(order[i:i + E.chunk]) for i in range(0, hi_id - lo_id, E.chunk)]
    stages = 0 if fixed else recipe.test.refinements
    if E.cycles is not None:
        slowest = np.array([float(period[cls[c]].max()) for c in chunks])
        stage_s = np.ceil(recipe.test.refine_cycles * _CYCLE_MARGIN * slowest * E.rate_hz) / E.rate_hz
        main = np.ceil(E.cycles * _CYCLE_MARGIN * slowest * E.rate_hz) / E.rate_hz
    else:
        stage_s = np.full(len(chunks), float(E.duration_s))
        main = np.full(len(chunks), float(E.duration_s))
    stage_s = stage_s if stages else np.zeros(len(chunks))
    durations = main + stages * stage_s
    sim_seeds = np.array([chunk_seed(recipe.seed, i, att_class) for i in range(len(chunks))], dtype=np.uint32)
    L = preprocess.input_length(grid)
    return Plan(recipe, g, att_class, class_index, beta, L, labels, K, bias, kind, level, y0, tau_obs, a_n, a0,
                effect_params, chunks, durations, sim_seeds, n_train=n, stage_s=stage_s)


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


def _effects(plan: Plan, ids: np.ndarray, samples: int) -> list:
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
        self.E = np.empty((relay.n, T))
        self.U = np.empty((relay.n, T))
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
            rf = refine_batch(t, np.nan_to_num(self.E[:, a:k]), self.U[:, a:k], beta=r.beta, tau_obs=r.tau_obs,
                              a_n=r.a_n, rate_hz=r.rate_hz, settle=STAGE_SETTLE * self.stage / r.rate_hz,
                              hover_a_n=self.hover_a_n)
            r.retune(rf["tau_obs"], rf["a_n"])
            self.history.append((r.tau_obs.copy(), r.a_n.copy()))
        u = self.relay(e)
        if k < self.E.shape[1]:
            self.E[:, k] = e
            self.U[:, k] = u
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
        return NPMRFT(plan.beta, r.test.h, plan.tau_obs[ids], plan.a_n[ids], rate, m, bias=plan.bias[ids])
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 1]))
    steps = int(round(HOVER_S * rate))
    eff = _noise_effect(r.noise.kinds, plan.noise_kind[ids], plan.noise_level[ids] * plan.a0[ids], steps)
    hover = synthetic_hover(m, HOVER_S, rate, plan.a0[ids], eff, rng)
    tau, a_n, q = np.empty(m), np.empty(m), np.empty(m)
    for i, est in enumerate(estimate_noise_batch(hover, rate)):
        tau[i], a_n[i] = recommend(est, plan.beta)
        q[i] = est.a_n
    relay = NPMRFT(plan.beta, r.test.h, tau, a_n, rate, m, bias=plan.bias[ids])
    stage = int(round(float(plan.stage_s[chunk]) * rate))
    return RefiningRelay(relay, stage, r.test.refinements, q)


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
    samples = int(round(duration_s * r.episodes.rate_hz))
    lb = LoopBatch(params, dt=r.episodes.dt, rate_hz=r.episodes.rate_hz, effects=_effects(plan, ids, samples), seed=seed,
                   nthread=nthread, y0=plan.y0[ids])
    ctrl = episode_controller(plan, ids, chunk, seed)
    res = lb.run(ctrl, duration_s)
    relay = ctrl.relay if isinstance(ctrl, RefiningRelay) else ctrl
    resp: dict[str, np.ndarray] = {}
    X, period, amp, ok = preprocess.features_batch(
        np.nan_to_num(res.y), res.u, r.episodes.rate_hz, np.full(m, r.test.h), plan.bias[ids], plan.L,
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
    params = [replace(plan.grid.params_of(int(plan.class_index[plan.labels[e]])), K=float(plan.K[e])) for e in ids]
    return run_episodes(params, plan, ids, float(plan.durations[index]), int(plan.sim_seeds[index]), nthread, index)


@functools.lru_cache(maxsize=4)
def _cached_plan(text: str, source: str, name: str, att_class: int | None) -> Plan:
    recipe = parse_recipe(text, source, name)
    return make_plan(recipe, load_family_grid(recipe), att_class)


def chunk_task(text: str, source: str, name: str, att_class: int | None, index: int) -> dict[str, np.ndarray]:
    """Dask task: one chunk, from the recipe text (workers rebuild and cache the plan)."""
    return run_chunk(_cached_plan(text, source, name, att_class), index, nthread=1)


# --- resume state ---------------------------------------------------------------------------------

class _Resume:
    """Finished chunks of one output file, saved atomically under ``OUT.resume/``."""

    def __init__(self, out: Path, plan: Plan):
        self.dir = out.with_name(out.name + ".resume")
        self.key = {"recipe_hash": plan.recipe.hash, "att_class": plan.att_class, "n_chunks": len(plan.chunks),
                    "format": FORMAT, "relay_reading": READING}
        state = self.dir / "state.json"
        if self.dir.exists():
            try:
                old = json.loads(state.read_text())
            except (OSError, ValueError):
                old = None
            if old != self.key:
                print(f"generate: {self.dir} is from another recipe; starting over", file=sys.stderr, flush=True)
                shutil.rmtree(self.dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        if not state.exists():
            state.write_text(json.dumps(self.key))

    def path(self, i: int) -> Path:
        return self.dir / f"chunk_{i:05d}.npz"

    def done(self) -> set[int]:
        out = set()
        for p in self.dir.glob("chunk_*.npz"):
            try:
                out.add(int(p.stem.split("_")[1]))
            except ValueError:
                continue
        return out

    def save(self, i: int, result: dict[str, np.ndarray]) -> None:
        tmp = self.dir / f".chunk_{i:05d}.tmp.npz"
        np.savez(tmp, **result)
        os.replace(tmp, self.path(i))

    def load(self, i: int) -> dict[str, np.ndarray]:
        try:
            with np.load(self.path(i)) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise UserError(f"resume state {self.path(i)} is unreadable ({exc}); delete {self.dir} to start over") \
                from None

    def clear(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


# --- progress ------------------------------------------------------------------------------------

def _fmt_s(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(round(s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


class _Progress:
    def __init__(self, plan: Plan, label: str, done: set[int], enabled: bool):
        self.plan, self.label, self.enabled = plan, label, enabled
        self.t0 = time.perf_counter()
        self.sizes = np.array([len(c) for c in plan.chunks])
        self.work = self.sizes * plan.durations  # simulated seconds, the cost of a chunk
        self.done = set(done)
        self.resumed_work = float(self.work[list(done)].sum()) if done else 0.0
        n_cls = len(plan.class_index)
        # a class is complete when its training episodes are (reference episodes run last)
        self.left = np.bincount(plan.labels[:plan.n_train], minlength=n_cls)
        for i in done:
            self.left -= np.bincount(self._train_labels(i), minlength=n_cls)
        if enabled and done:
            print(f"{label}: resuming, {len(done)}/{len(plan.chunks)} chunks already done", file=sys.stderr,
                  flush=True)

    def _train_labels(self, i: int) -> np.ndarray:
        ids = self.plan.chunks[i]
        return self.plan.labels[ids[ids < self.plan.n_train]]

    def chunk(self, i: int) -> None:
        self.done.add(i)
        labels = self.plan.labels[self.plan.chunks[i]]
        self.left -= np.bincount(self._train_labels(i), minlength=len(self.left))
        if not self.enabled:
            return
        el = time.perf_counter() - self.t0
        w_done = float(self.work[list(self.done)].sum())
        w_new = w_done - self.resumed_work
        eta = (float(self.work.sum()) - w_done) * el / w_new if w_new > 0 else float("nan")
        eps = int(self.sizes[list(self.done)].sum())
        cls = sorted({int(self.plan.class_index[c]) for c in np.unique(labels)})
        finished = int(np.sum(self.left == 0))
        print(f"{self.label}: chunk {len(self.done)}/{len(self.plan.chunks)} (classes {cls[0]}..{cls[-1]}) | "
              f"episodes {eps}/{self.plan.n} ({100 * eps / max(self.plan.n, 1):.0f}%) | "
              f"classes complete {finished}/{len(self.left)} | elapsed {_fmt_s(el)} ETA {_fmt_s(eta)}",
              file=sys.stderr, flush=True)


# --- backends ------------------------------------------------------------------------------------

def _dask_client(backend: str):
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:  # pragma: no cover - dask is a dependency
        raise UserError("the dask backend needs dask[distributed]") from None
    if backend.startswith("local:"):
        try:
            n = int(backend.split(":", 1)[1])
        except ValueError:
            n = 0
        if n < 1:
            raise UserError(f"--dask expects local:N with N >= 1, got {backend!r}")
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
        return Client(cluster), cluster
    try:
        return Client(backend, timeout="20s"), None
    except (OSError, TimeoutError) as exc:
        raise UserError(f"cannot reach the Dask scheduler at {backend}: {exc}") from None


def _run_threads(plan: Plan, todo: list[int], workers: int, on_result: Callable[[int, dict], None]) -> None:
    # Every batch gets all CPUs: while one chunk runs its numpy controller the other's
    # physics uses them, and the last chunk left alone is not held to cpus / workers
    # (measured: ratio to raw 0.86-1.04 against 0.81 with cpus / workers threads each).
    nthread = os.cpu_count() or 1
    workers = max(1, min(workers, len(todo))) if todo else 1
    ex = cf.ThreadPoolExecutor(max_workers=workers)
    try:
        futs = {ex.submit(run_chunk, plan, i, nthread): i for i in todo}
        for f in cf.as_completed(futs):
            on_result(futs[f], f.result())
    finally:
        ex.shutdown(wait=False, cancel_futures=True)


def _run_dask(plan: Plan, todo: list[int], client, on_result: Callable[[int, dict], None]) -> None:
    from dask.distributed import as_completed

    r = plan.recipe
    futs = {}
    for i in todo:
        key = f"uavsim-chunk-{r.hash[:16]}-{plan.att_class}-{i}"
        futs[client.submit(chunk_task, r.text, r.source, r.name, plan.att_class, i, key=key, retries=2)] = i
    from distributed import KilledWorker

    try:
        for f in as_completed(list(futs)):
            try:
                res = f.result()
            except KilledWorker as exc:
                raise UserError(f"chunk {futs[f]} killed its Dask workers repeatedly ({exc}); finished chunks are "
                                f"saved, run again to continue") from None
            on_result(futs[f], res)
    finally:
        for f in futs:
            f.cancel()


# --- metadata ------------------------------------------------------------------------------------

def versions() -> dict[str, str]:
    """Versions of what shapes the data (stored in the file as JSON)."""
    import h5py
    import mujoco

    import uavsim

    return {"python": sys.version.split()[0], "numpy": np.__version__, "mujoco": mujoco.__version__,
            "h5py": h5py.__version__, "uavsim": getattr(uavsim, "__version__", "unknown")}


#: versions a Dask worker must share with the client (they change the simulated episodes)
MATCHED_VERSIONS = ("uavsim", "mujoco", "numpy")


def cluster_versions(client) -> dict[str, str]:
    """The Dask workers' ``versions()``, refused (``UserError``) where uavsim, MuJoCo or numpy differ from this
    process's; the result (what the file records) is the workers', with this process's h5py (it writes the file)."""
    mine = versions()
    try:
        theirs = client.run(versions)
    except Exception as exc:  # noqa: BLE001 - a worker that cannot import uavsim fails here, with any error
        raise UserError(f"the Dask workers cannot report their versions ({type(exc).__name__}: {exc}); "
                        "install this uavsim on every worker") from None
    if not theirs:
        raise UserError("the Dask cluster has no workers")
    for addr, v in sorted(theirs.items()):
        diff = [k for k in MATCHED_VERSIONS if v.get(k) != mine.get(k)]
        if diff:
            w, c = (", ".join(f"{k} {d.get(k)}" for k in diff) for d in (v, mine))
            raise UserError(f"Dask worker {addr} runs {w}, this client {c}: install the same "
                            "versions on every worker (the episodes depend on them)")
    first = theirs[sorted(theirs)[0]]
    return {**first, "h5py": mine["h5py"]}


def git_commit() -> str:
    """Commit of the uavsim checkout ("unknown" outside git), read-only."""
    root = Path(__file__).resolve().parents[2]
    try:
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() if out.returncode == 0 else "unknown"


def class_table_gains(family: str, rate_hz: float, att_class: int | None) -> dict[str, np.ndarray]:
    """The grid's table of ISE-optimal PDs at the data's control rate, as class-table columns.

    ``table_kp``, ``table_kd`` (the class's own optimum), ``table_robust_kp``, ``table_robust_kd`` (the
    answer identification gives), ``table_filter_hz``, ``table_omega`` and ``table_gain_at_omega`` (the
    gain estimate's reference), each (n,) for K = 1, and ``J``: the table's robust answers' relative
    sensitivity (n, n), which the network's loss weighs (``uavsim.tuning.table``).
    """
    from uavsim.tuning.table import load_table

    t = load_table(family, rate_hz)
    if att_class is not None:
        t = t.lateral(att_class)
    return {"table_kp": t.kp, "table_kd": t.kd, "table_robust_kp": t.robust_kp, "table_robust_kd": t.robust_kd,
            "table_filter_hz": t.derivative_filter_hz, "table_omega": t.omega,
            "table_gain_at_omega": t.gain_at_omega, "J": np.asarray(t.J_robust, dtype=np.float64)}


def _assemble(plan: Plan, results: dict[int, dict], out: Path, run_versions: dict[str, str] | None = None
              ) -> dict[str, Any]:
    n = plan.n
    r = plan.recipe
    C, L = len(preprocess.CHANNELS), plan.L
    X = np.zeros((n, C, L), dtype=np.float32)
    period, amp = np.full(n, np.nan), np.full(n, np.nan)
    resp, resp_period = np.full(n, complex("nan")), np.full(n, np.nan)
    ok, div = np.zeros(n, bool), np.zeros(n, bool)
    tau_obs, a_n = plan.tau_obs.copy(), plan.a_n.copy()
    seed_of = np.zeros(n, dtype=np.uint32)
    keep_raw = r.preprocess.keep_raw
    Tmax = int(round(plan.durations.max() * r.episodes.rate_hz)) if keep_raw else 0
    raw_y = np.full((n, Tmax), np.nan, np.float32) if keep_raw else None
    raw_u = np.full((n, Tmax), np.nan, np.float32) if keep_raw else None
    length = np.zeros(n, np.int64)
    for i, res in results.items():
        ids = res["ids"]
        X[ids], period[ids], amp[ids], ok[ids], div[ids] = res["X"], res["period"], res["amplitude"], res["ok"], \
            res["diverged"]
        if "response" in res:  # chunks saved by an older version for resume lack it
            resp[ids], resp_period[ids] = res["response"], res["response_period"]
        if "tau_obs" in res:
            tau_obs[ids], a_n[ids] = res["tau_obs"], res["a_n"]
        seed_of[ids] = plan.sim_seeds[i]
        if keep_raw:
            T = res["y"].shape[1]
            raw_y[ids, :T], raw_u[ids, :T], length[ids] = res["y"], res["u"], T
    nt = plan.n_train
    keep = np.flatnonzero(ok[:nt] & np.isfinite(X[:nt]).all(axis=(1, 2)))
    g = plan.grid
    ci = plan.class_index
    fam = r.loop
    classes = {k: np.asarray(g.params[k], float)[ci] for k in CLASS_PARAMS[fam]}
    classes.update({k: np.asarray(getattr(g, k), float)[ci] for k in CLASS_FIELDS})
    classes["grid_index"] = ci.astype(np.float64)
    # the reference episodes' cycle (K = 1, h = 1 scale): NaN where it failed
    classes["period_sim"] = period[nt:].copy()
    classes["amplitude_sim"] = amp[nt:] / r.test.h
    tab = class_table_gains(fam, r.episodes.rate_hz, plan.att_class)
    classes.update({k: v[ci] for k, v in tab.items() if k != "J"})
    J = tab["J"][np.ix_(ci, ci)]
    fixed = r.test.settings == "fixed"
    episodes = {"inputs": X[keep], "labels": plan.labels[keep], "K": plan.K[keep], "bias": plan.bias[keep],
                "noise_kind": plan.noise_kind[keep], "noise_level": plan.noise_level[keep], "period": period[keep],
                "amplitude": amp[keep], "y0": plan.y0[keep], "tau_obs": tau_obs[keep], "a_n": a_n[keep],
                "episode": keep, "sim_seed": seed_of[keep], "response_re": resp[keep].real,
                "response_im": resp[keep].imag, "response_period": resp_period[keep]}
    n_div = int(div[:nt].sum())
    attrs = {"loop": fam, "grid_hash": g.hash or "", "grid_version": int(g.version), "beta": plan.beta,
             "h": r.test.h, "relay_reading": READING, "relay_settings": r.test.settings,
             "tau_obs": r.test.tau_obs if fixed else float("nan"), "a_n": r.test.a_n if fixed else float("nan"),
             "refinements": 0 if fixed else r.test.refinements, "rate_hz": r.episodes.rate_hz,
             "dt": r.episodes.dt, "input_length": L, "input_rate_hz": preprocess.INPUT_RATE_HZ,
             "channels": list(preprocess.CHANNELS), "cycles_per_input": r.preprocess.cycles,
             "noise_kinds": list(r.noise.kinds), "recipe": r.text, "seed": r.seed,
             "versions": json.dumps(run_versions or versions(), sort_keys=True), "git_commit": git_commit(), "n_episodes": nt,
             "n_diverged": n_div, "n_rejected": int(nt - n_div - len(keep)),
             "J_source": f"table robust answers at {r.episodes.rate_hz:g} Hz (J of table_robust_kp/kd)",
             "simulated_s": float(sum(len(c) * d for c, d in zip(plan.chunks, plan.durations, strict=True)))}
    if plan.att_class is not None:
        attrs["att_class"] = int(plan.att_class)
    effects = {k: v[keep] for k, v in plan.effect_params.items()}
    raw = {"y": raw_y[keep], "u": raw_u[keep], "length": length[keep]} if keep_raw else None
    write_dataset(out, episodes, classes, J, attrs, effects=effects, raw=raw)
    return {"file": str(out), "n_episodes": nt, "n_kept": int(len(keep)), "n_diverged": n_div,
            "n_rejected": attrs["n_rejected"], "simulated_s": attrs["simulated_s"]}


def output_paths(recipe: Recipe, out: str | Path | None, grid) -> list[tuple[int | None, Path]]:
    """(attitude class, file) of each file a recipe makes: ``OUT`` or ``OUT_aNN.h5`` for lateral."""
    base = Path(out) if out is not None else Path(recipe.source).with_suffix(".h5")
    if base.suffix != ".h5":
        raise UserError(f"output {base} must end in .h5")
    atts = att_classes_of(recipe, grid)
    if atts == [None]:
        return [(None, base)]
    return [(a, base.with_name(f"{base.stem}_a{a:02d}.h5")) for a in atts]


def generate(recipe: Recipe, out_path: str | Path | None = None, *, backend: str = "threads",
             workers: int | None = None, progress: bool = True,
             on_chunk: Callable[[int], None] | None = None, client=None) -> dict[str, Any]:
    """Generate the dataset file(s) of ``recipe``.

    Parameters
    ----------
    recipe : Recipe
    out_path : file (default: the recipe's path with ``.h5``); lateral recipes write
        ``STEM_aNN.h5`` per attitude class next to it.
    backend : ``"threads"``, ``"dask:local:N"`` or ``"dask:ADDRESS"`` (a scheduler address)
    workers : threads of the threads backend (default: 2, or the CPU count if smaller)
    progress : print progress on stderr
    on_chunk : called with each chunk index after it is saved (tests use it to interrupt)
    client : a ``dask.distributed.Client`` to run the chunks on (overrides ``backend``; not closed)

    Returns
    -------
    dict: ``files``, ``n_episodes``, ``n_kept``, ``n_diverged``, ``n_rejected``,
    ``simulated_s`` (this call's simulation), ``wall_s``, ``episodes_per_s``,
    ``sim_s_per_wall_s`` (this call only: resumed chunks are not counted).
    """
    grid = load_family_grid(recipe)
    t0 = time.perf_counter()
    own = client is None
    cluster = None
    if client is not None:
        pass
    elif backend.startswith("dask:"):
        client, cluster = _dask_client(backend[5:])
    elif backend != "threads":
        raise UserError(f"unknown backend {backend!r} (threads, dask:local:N, dask:ADDRESS)")
    workers = workers or min(2, os.cpu_count() or 1)
    summary: dict[str, Any] = {"files": [], "n_episodes": 0, "n_kept": 0, "n_diverged": 0, "n_rejected": 0,
                               "simulated_s": 0.0, "episodes_run": 0}
    try:
        # the chunks are simulated where they run: a cluster must run this uavsim, MuJoCo and numpy,
        # and the file records the workers' versions
        run_versions = cluster_versions(client) if client is not None else None
        for att, out in output_paths(recipe, out_path, grid):
            plan = make_plan(recipe, grid, att)
            state = _Resume(out, plan)
            done = state.done()
            todo = [i for i in range(len(plan.chunks)) if i not in done]
            # longest first: the last chunks to finish are short, so no thread idles long at the end
            todo.sort(key=lambda i, plan=plan: -len(plan.chunks[i]) * plan.durations[i])
            label = f"generate {out.name}"
            prog = _Progress(plan, label, done, progress)

            def on_result(i: int, res: dict, state=state, prog=prog, plan=plan) -> None:
                state.save(i, res)
                summary["simulated_s"] += float(len(plan.chunks[i]) * plan.durations[i])
                summary["episodes_run"] += len(plan.chunks[i])
                prog.chunk(i)
                if on_chunk is not None:
                    on_chunk(i)

            try:
                if client is not None:
                    _run_dask(plan, todo, client, on_result)
                else:
                    _run_threads(plan, todo, workers, on_result)
            except KeyboardInterrupt:
                if progress:
                    print(f"{label}: interrupted with {len(state.done())}/{len(plan.chunks)} chunks saved in "
                          f"{state.dir}; run the same command again to continue", file=sys.stderr, flush=True)
                raise
            results = {i: state.load(i) for i in range(len(plan.chunks))}
            s = _assemble(plan, results, out, run_versions)
            state.clear()
            summary["files"].append(s["file"])
            for k in ("n_episodes", "n_kept", "n_diverged", "n_rejected"):
                summary[k] += s[k]
            if progress:
                print(f"{label}: wrote {out} ({s['n_kept']} inputs; {s['n_diverged']} diverged, "
                      f"{s['n_rejected']} rejected)", file=sys.stderr, flush=True)
            if s["n_kept"] < 0.5 * s["n_episodes"]:
                msg = (f"{out}: only {s['n_kept']} of {s['n_episodes']} episodes kept ({s['n_diverged']} diverged, "
                       f"{s['n_rejected']} rejected): check the recipe (dt, h, noise) and the grid")
                summary.setdefault("warnings", []).append(msg)
                print(f"{label}: WARNING {msg}", file=sys.stderr, flush=True)
    finally:
        if client is not None and own:
            client.close()
        if cluster is not None:
            cluster.close()
    wall = time.perf_counter() - t0
    summary["wall_s"] = wall
    summary["episodes_per_s"] = summary["episodes_run"] / wall if wall > 0 else float("nan")
    summary["sim_s_per_wall_s"] = summary["simulated_s"] / wall if wall > 0 else float("nan")
    return summary


def _process_prediction(p: LumpedParams, beta: float, h: float) -> tuple[float, float]:
    from uavsim.lumped.simulate import fourier_limit_cycle

    return fourier_limit_cycle(p, beta, h)


def simulate_features(params: list[LumpedParams], recipe: Recipe, seed: int, *,
                      noise: tuple[np.ndarray, np.ndarray] | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Episodes of given (off-grid) processes through the generation path.

    The recipe's test, randomization (bias, noise, initial output, effects),
    episode settings and preprocessing apply; the gain is each process's own
    ``K`` (not randomized); the input length is the recipe grid's. The expected
    amplitude and period (noise level, tau_obs cap, episode length) come from the
    exact relay cycle of each process (``fourier_limit_cycle``). ``noise``, when
    given, is each episode's noise kind (index into ``recipe.noise.kinds``) and
    level (fraction of that amplitude) instead of the recipe's draw (which still
    takes place: the other draws do not move).

    Returns
    -------
    X : (n, C, L) float32, period : (n,) s, amplitude : (n,) output units, ok : (n,) bool,
    meta : dict of per-episode draws (``K, bias, noise_kind, noise_level, y0, tau_obs, a_n``,
    (n,) arrays), ``noise_kinds``, ``diverged`` (n,), ``seed``, ``duration_s``, ``response``
    (n,) complex and ``response_period`` (n,) s (the fundamental response), ``harmonics_y``,
    ``harmonics_u`` (n, HARMONICS) complex (``preprocess.CycleFeatures``), and ``y``, ``u`` (n, T)
    when the recipe keeps raw traces.
    """
    if not params:
        raise UserError("simulate_features needs at least one process")
    grid = load_family_grid(recipe)
    n = len(params)
    sub = grid.lateral(recipe.att_classes[0] if recipe.att_classes else 0) if recipe.loop == "lateral" else grid
    beta = recipe.test.beta if recipe.test.beta is not None else float(sub.beta)
    h, E = recipe.test.h, recipe.episodes
    pred = np.array([_process_prediction(p, beta, h) for p in params])
    T0, a0 = pred[:, 0], pred[:, 1]
    rng = np.random.default_rng(seed)
    bias = rng.uniform(-recipe.randomize.bias, recipe.randomize.bias, n) * h
    w = np.asarray(recipe.noise.weights, dtype=float)
    kind = rng.choice(len(w), size=n, p=w / w.sum()).astype(np.int8)
    level = rng.uniform(*recipe.noise.level, n)
    level[np.array([recipe.noise.kinds[k] == "none" for k in kind], dtype=bool)] = 0.0
    if noise is not None:
        kind = np.asarray(noise[0], dtype=np.int8).reshape(n)
        level = np.asarray(noise[1], dtype=np.float64).reshape(n)
    y0 = rng.uniform(-1.0, 1.0, n) * recipe.randomize.y0 * a0
    effect_params = {f"{i}_{fx.name}/{k}": rng.uniform(v[0], v[1], n)
                     for i, fx in enumerate(recipe.effects) for k, v in fx.params.items() if isinstance(v, tuple)}
    fixed = recipe.test.settings == "fixed"
    if fixed:
        tau_obs = np.array([max(min(recipe.test.tau_obs, tau_obs_max(beta, float(t), E.rate_hz)), 1.0 / E.rate_hz)
                            for t in T0])
        a_n = recipe.test.a_n * level * a0
    else:
        tau_obs, a_n = np.full(n, np.nan), np.full(n, np.nan)
    K = np.array([p.K for p in params])
    stages = 0 if fixed else recipe.test.refinements
    if E.cycles is not None:
        main = math.ceil(E.cycles * _CYCLE_MARGIN * float(T0.max()) * E.rate_hz) / E.rate_hz
        stage = math.ceil(recipe.test.refine_cycles * _CYCLE_MARGIN * float(T0.max()) * E.rate_hz) / E.rate_hz
    else:
        main = stage = float(E.duration_s)
    stage = stage if stages else 0.0
    duration = main + stages * stage
    ids = np.arange(n)
    plan = Plan(recipe, sub, None, np.arange(1), beta, preprocess.input_length(grid), np.zeros(n, np.int32), K,
                bias, kind, level, y0, tau_obs, a_n, a0, effect_params, [ids],
                np.array([duration]), np.array([chunk_seed(seed, 0)], dtype=np.uint32), n_train=n,
                stage_s=np.array([stage]))
    res = run_episodes(list(params), plan, ids, duration, int(plan.sim_seeds[0]))
    meta = {"K": K, "bias": bias, "noise_kind": kind, "noise_kinds": list(recipe.noise.kinds), "noise_level": level,
            "y0": y0, "tau_obs": res["tau_obs"], "a_n": res["a_n"], "diverged": res["diverged"], "seed": seed,
            "duration_s": duration, "expected_period": T0, "expected_amplitude": a0, "effects": effect_params,
            "response": res["response"], "response_period": res["response_period"],
            "harmonics_y": res["harmonics_y"], "harmonics_u": res["harmonics_u"]}
    if "y" in res:
        meta["y"], meta["u"] = res["y"], res["u"]
    return res["X"], res["period"], res["amplitude"], res["ok"], meta

