"""The plan of a training set: every episode's draws, fixed before anything runs.

All per-episode draws (gain factor, relay bias, noise kind and level, initial
output, randomized effect parameters) come from one
``np.random.default_rng(recipe.seed)`` in a fixed order; episodes are sorted by
class period and cut into chunks, each with its own simulation seed
(:func:`chunk_seed`). See :mod:`uavsim.data.generate`.

Off-centre episodes (``[randomize] offgrid``, a share of each class's): the
process is drawn uniformly (log scale) from the class's cell, the part of the
loop's box (``uavsim.lumped.params.RANGES``) nearer to that class's centre than
to any other class's in normalized log coordinates, the distance identification's
evaluation calls the nearest class. The cells tile the box, so the set covers
the processes a flight (and ``uavsim evaluate``) meets, each labelled by its
nearest class; the J of the table is exact only at the centres, so such a set
stores each sample's own cost vector (:mod:`uavsim.data.costs`). Those draws come
after every other draw of the generator: the other draws are those of the same
recipe without ``offgrid``.

    plan = make_plan(recipe, load_family_grid(recipe))
    plan.n, plan.chunks[0], plan.sim_seeds[0]
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from uavsim.data import preprocess
from uavsim.data.recipe import Recipe
from uavsim.errors import UserError
from uavsim.noise.estimate import (
    tau_obs_max,
)

#: extra length over ``cycles`` slowest-class periods: noise and NP-MRFT lengthen cycles
CYCLE_MARGIN = 1.15
#: s: the hover segment whose noise estimate gives a recommended episode its first settings
HOVER_S = 10.0
#: of a refinement stage: the transient skipped before its samples are analysed
STAGE_SETTLE = 0.25


@dataclass(kw_only=True)
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
    process: dict[str, np.ndarray] | None = None  # offgrid: (n,) T_prop, T1, tau of every episode
    offgrid: np.ndarray | None = None  # offgrid: (n,) bool, the episode is off its class centre

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
    period = np.asarray(g.period, dtype=float)
    ep_amp, ep_period = np.asarray(g.amplitude, dtype=float)[cls], period[cls]
    process = off = None
    if recipe.randomize.offgrid > 0:
        process, off, ep_amp, ep_period = _offgrid(recipe, g, rng, labels, class_index, beta)
    a0 = ep_amp * K * h
    y0 = y0u * recipe.randomize.y0 * a0
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
    ref_cls = class_index[ref]
    ep_amp = np.concatenate([ep_amp, np.asarray(g.amplitude, dtype=float)[ref_cls]])
    ep_period = np.concatenate([ep_period, period[ref_cls]])
    if process is not None:
        process = {k: np.concatenate([v, np.asarray(g.params[k], dtype=float)[ref_cls]]) for k, v in process.items()}
        off = np.concatenate([off, np.zeros(nc, bool)])
    a0 = ep_amp * K * h
    # chunks: episodes by (expected) period (stable), so a chunk's length follows similar classes
    chunks = []
    for lo_id, hi_id in ((0, n), (n, n + nc)):
        order = lo_id + np.argsort(ep_period[lo_id:hi_id], kind="stable")
        chunks += [np.sort(order[i:i + E.chunk]) for i in range(0, hi_id - lo_id, E.chunk)]
    stages = 0 if fixed else recipe.test.refinements
    if E.cycles is not None:
        slowest = np.array([float(ep_period[c].max()) for c in chunks])
        stage_s = np.ceil(recipe.test.refine_cycles * CYCLE_MARGIN * slowest * E.rate_hz) / E.rate_hz
        main = np.ceil(E.cycles * CYCLE_MARGIN * slowest * E.rate_hz) / E.rate_hz
    else:
        stage_s = np.full(len(chunks), float(E.duration_s))
        main = np.full(len(chunks), float(E.duration_s))
    stage_s = stage_s if stages else np.zeros(len(chunks))
    durations = main + stages * stage_s
    sim_seeds = np.array([chunk_seed(recipe.seed, i, att_class) for i in range(len(chunks))], dtype=np.uint32)
    L = preprocess.input_length(grid)
    return Plan(recipe=recipe, grid=g, att_class=att_class, class_index=class_index, beta=beta, L=L, labels=labels,
                K=K, bias=bias, noise_kind=kind, noise_level=level, y0=y0, tau_obs=tau_obs, a_n=a_n, a0=a0,
                effect_params=effect_params, chunks=chunks, durations=durations, sim_seeds=sim_seeds, n_train=n,
                stage_s=stage_s, process=process, offgrid=off)


#: candidate points per round of the cell draw (rejection by nearest class)
_CELL_BATCH = 65536


def _offgrid(recipe: Recipe, g, rng: np.random.Generator, labels: np.ndarray, class_index: np.ndarray, beta: float
             ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """Off-centre processes of the training episodes (module docstring).

    The first ``round(offgrid * per_class)`` episodes of each class are drawn in its cell:
    points uniform in the normalized log box, in rounds of ``_CELL_BATCH``, each kept by the
    class it is nearest to until every class has its share. Their expected cycle (noise level,
    initial output, episode length) is the class's exact one times the describing-function
    ratio of the drawn process to the class centre.

    Returns the (n,) ``T_prop``, ``T1``, ``tau``, the off-centre mask, and each episode's cycle
    amplitude and period at K = 1, h = 1.
    """
    from uavsim.lumped.frequency import mrft_prediction_batch
    from uavsim.lumped.params import BOX_KEYS, box_coordinates, from_box_coordinates, nearest_centre

    loop = recipe.loop
    keys = BOX_KEYS[loop]
    per = recipe.episodes.per_class
    share = int(round(recipe.randomize.offgrid * per))
    centres = box_coordinates(loop, g.params)  # every grid class
    n = len(labels)
    off = (np.arange(n) % per) < share
    want = {int(c): share for c in class_index}
    got: dict[int, list[np.ndarray]] = {c: [] for c in want}
    for _ in range(10_000):
        if all(v == 0 for v in want.values()):
            break
        u = rng.uniform(0.0, 1.0, (_CELL_BATCH, 3))
        near = nearest_centre(u, centres)
        for c in want:
            if want[c]:
                pts = u[near == c][: want[c]]
                got[c].append(pts)
                want[c] -= len(pts)
    else:
        raise UserError(f"{recipe.source}: could not fill the classes' cells (a class with no cell in the box?)")
    P = {k: np.asarray(g.params[k], dtype=float)[class_index[labels]] for k in keys}
    for j, c in enumerate(class_index):
        ids = np.flatnonzero(off & (labels == j))
        for k, v in from_box_coordinates(loop, np.concatenate(got[int(c)])).items():
            P[k][ids] = v
    fam = "altitude" if loop == "altitude" else "attitude"
    centre = {k: np.asarray(g.params[k], dtype=float)[class_index[labels]] for k in keys}
    w_c, a_c = mrft_prediction_batch(fam, beta, 1.0, K=np.ones(n), **centre)
    w_p, a_p = mrft_prediction_batch(fam, beta, 1.0, K=np.ones(n), **P)
    cls = class_index[labels]
    amp = np.asarray(g.amplitude, dtype=float)[cls]
    period = np.asarray(g.period, dtype=float)[cls]
    amp = np.where(off, amp * a_p / a_c, amp)
    period = np.where(off, period * w_c / w_p, period)
    return P, off, amp, period
