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
  longest first, each ``LoopBatch`` on its share of the CPUs and the last on
  all (``chunk_threads``: the numpy controller of one chunk overlaps the
  physics of another without oversubscribing the cores). ``dask``: chunks are Dask distributed
  tasks (``local:N`` starts a LocalCluster of N one-thread workers, or a
  scheduler address); a lost worker's tasks are re-run by Dask, and as they are
  pure, the file is the same.

The steps live in their own modules: the plan (:mod:`uavsim.data.plan`), the
episodes (:mod:`uavsim.data.episodes`), the backends and resume state
(:mod:`uavsim.data.backends`) and the file (:mod:`uavsim.data.assemble`);
their public names are also importable from here.

    from uavsim.data.recipe import load_recipe
    from uavsim.data.generate import generate
    summary = generate(load_recipe("datasets/small.toml"), "datasets/small.h5")
    summary["files"], summary["episodes_per_s"]
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.cpus import available_cpus
from uavsim.data import preprocess
from uavsim.data.assemble import assemble, class_table_gains, output_paths
from uavsim.data.backends import (
    MATCHED_VERSIONS,
    Progress,
    ResumeState,
    cluster_versions,
    dask_client,
    finished_file,
    git_commit,
    run_dask,
    run_threads,
    versions,
)
from uavsim.data.episodes import (
    RefiningRelay,
    chunk_params,
    chunk_task,
    episode_batch,
    episode_controller,
    episode_effects,
    run_chunk,
    run_episodes,
)
from uavsim.data.plan import CYCLE_MARGIN as _CYCLE_MARGIN  # the name simulate_features uses
from uavsim.data.plan import (
    HOVER_S,
    STAGE_SETTLE,
    Plan,
    att_classes_of,
    chunk_seed,
    load_family_grid,
    make_plan,
)
from uavsim.data.recipe import Recipe
from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams
from uavsim.noise.estimate import tau_obs_max

__all__ = [
    "generate",
    "simulate_features",
    "Plan",
    "make_plan",
    "chunk_seed",
    "load_family_grid",
    "att_classes_of",
    "HOVER_S",
    "STAGE_SETTLE",
    "RefiningRelay",
    "episode_controller",
    "episode_effects",
    "chunk_params",
    "episode_batch",
    "run_episodes",
    "run_chunk",
    "chunk_task",
    "ResumeState",
    "Progress",
    "run_threads",
    "run_dask",
    "dask_client",
    "versions",
    "cluster_versions",
    "MATCHED_VERSIONS",
    "git_commit",
    "class_table_gains",
    "assemble",
    "output_paths",
]


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
        client, cluster = dask_client(backend[5:])
    elif backend != "threads":
        raise UserError(f"unknown backend {backend!r} (threads, dask:local:N, dask:ADDRESS)")
    workers = workers or min(2, available_cpus())
    summary: dict[str, Any] = {"files": [], "n_episodes": 0, "n_kept": 0, "n_diverged": 0, "n_rejected": 0,
                               "simulated_s": 0.0, "episodes_run": 0}
    try:
        # the chunks are simulated where they run: a cluster must run this uavsim, MuJoCo and numpy,
        # and the file records the workers' versions
        run_versions = cluster_versions(client) if client is not None else None
        for att, out in output_paths(recipe, out_path, grid):
            plan = make_plan(recipe, grid, att)
            if att is not None and finished_file(out, plan):
                summary["files"].append(str(out))
                if progress:
                    print(f"generate {out.name}: complete from this recipe and grid, kept", file=sys.stderr, flush=True)
                continue
            state = ResumeState(out, plan)
            done = state.done()
            todo = [i for i in range(len(plan.chunks)) if i not in done]
            # longest first: the last chunks to finish are short, so no thread idles long at the end
            todo.sort(key=lambda i, plan=plan: -len(plan.chunks[i]) * plan.durations[i])
            label = f"generate {out.name}"
            prog = Progress(plan, label, done, progress)

            def on_result(i: int, res: dict, state=state, prog=prog, plan=plan) -> None:
                state.save(i, res)
                summary["simulated_s"] += float(len(plan.chunks[i]) * plan.durations[i])
                summary["episodes_run"] += len(plan.chunks[i])
                prog.chunk(i)
                if on_chunk is not None:
                    on_chunk(i)

            try:
                if client is not None:
                    run_dask(plan, todo, client, on_result)
                else:
                    run_threads(plan, todo, workers, on_result)
            except KeyboardInterrupt:
                if progress:
                    print(f"{label}: interrupted with {len(state.done())}/{len(plan.chunks)} chunks saved in "
                          f"{state.dir}; run the same command again to continue", file=sys.stderr, flush=True)
                raise
            results = {i: state.load(i) for i in range(len(plan.chunks))}
            s = assemble(plan, results, out, run_versions)
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
    ``harmonics_u`` (n, HARMONICS) complex (``preprocess.CycleFeatures``), ``run_start_s`` (the
    time the episode proper starts, after the refinement stages), and ``y``, ``u`` (n, T) when the
    recipe keeps raw traces (from the first stage on).
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
    plan = Plan(recipe=recipe, grid=sub, att_class=None, class_index=np.arange(1), beta=beta,
                L=preprocess.input_length(grid), labels=np.zeros(n, np.int32), K=K, bias=bias, noise_kind=kind,
                noise_level=level, y0=y0, tau_obs=tau_obs, a_n=a_n, a0=a0, effect_params=effect_params,
                chunks=[ids], durations=np.array([duration]),
                sim_seeds=np.array([chunk_seed(seed, 0)], dtype=np.uint32), n_train=n, stage_s=np.array([stage]))
    res = run_episodes(list(params), plan, ids, duration, int(plan.sim_seeds[0]))
    meta = {"K": K, "bias": bias, "noise_kind": kind, "noise_kinds": list(recipe.noise.kinds), "noise_level": level,
            "y0": y0, "tau_obs": res["tau_obs"], "a_n": res["a_n"], "diverged": res["diverged"], "seed": seed,
            "duration_s": duration, "run_start_s": stages * stage, "expected_period": T0, "expected_amplitude": a0,
            "effects": effect_params,
            "response": res["response"], "response_period": res["response_period"],
            "harmonics_y": res["harmonics_y"], "harmonics_u": res["harmonics_u"]}
    if "y" in res:
        meta["y"], meta["u"] = res["y"], res["u"]
    return res["X"], res["period"], res["amplitude"], res["ok"], meta

