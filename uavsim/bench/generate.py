"""``uavsim bench generate``: training-set generation throughput against raw MuJoCo stepping.

Measured in one run on the same episodes, so that the ratio does not depend on
how busy the machine is:

- generation: ``uavsim.data.generate.generate`` on an altitude recipe (a class
  subset, every noise kind), end to end: planning, NP-MRFT episodes in
  ``LoopBatch``, preprocessing and the HDF5 write; ``episodes_per_s`` and
  ``sim_s_per_wall_s`` (simulated seconds per wall second);
- raw: ``Batch.step`` alone on the same batches (same models, processes,
  substeps and episode lengths), no controller, no effects, no writing, each
  batch arranged three ways: one after another on all CPUs, two at a time on
  all CPUs each, and two at a time on each one's share of the CPUs with the
  last on all (``chunk_threads``, as generation runs them); the fastest
  arrangement is the baseline, ``raw_sim_s_per_wall_s``;
- ``ratio_to_raw`` = generation / raw (goal >= 0.90).

The four are interleaved ``--repeats`` times and each reported figure is the
best of its repeats (the machine is shared: the best run is the least disturbed).

Beside the wall figures, the process CPU time of each (``time.process_time``, all
threads) is reported as a diagnostic: ``gen_cpu_s`` and ``raw_cpu_s`` (the least
over every raw arrangement and repeat, the strictest baseline) and
``cpu_ratio_to_raw`` = raw / generation CPU seconds: the work generation adds to
the stepping. On a shared machine it moves much less than the wall ratio, whose
runs other jobs slow unequally (an arrangement with more threads gets a larger
share of a loaded machine). It is not the goal: an idle core costs wall time
but no CPU time.

    uavsim bench generate --json
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from uavsim.cli._common import eprint, print_result

BENCH_RECIPE = """\
# uavsim bench generate: a subset of the altitude grid, every noise kind
loop = "altitude"
seed = 3
classes = {classes}

[test]
settings = "recommended"

[episodes]
per_class = {per_class}
cycles = 6
dt = 0.001
rate_hz = 200.0
chunk = {chunk}

[randomize]
K = [0.5, 2.0]
bias = 0.5
y0 = 0.5

[noise]
kinds = ["none", "white", "paper", "coloured", "quantization", "outliers"]
level = [0.0, 0.2]
"""


#: raw arrangements: (batches at a time, physics threads per batch: "all" CPUs or generation's "split")
RAW_ARRANGEMENTS = {"sequential": (1, "all"), "concurrent": (2, "all"), "split": (2, "split")}


def _raw_wall(recipe, arrangement: str) -> tuple[float, float]:
    """Wall and process CPU seconds of ``Batch.step`` alone over every batch of the recipe's plan.

    Batches run longest first (as generation runs them), ``RAW_ARRANGEMENTS[arrangement]``:
    one after another on all CPUs, two at a time on all CPUs each, or two at a time with
    generation's threads per batch (``chunk_threads``: a share each, the last on all).
    """
    from uavsim.cpus import available_cpus
    from uavsim.data.backends import chunk_threads
    from uavsim.data.generate import load_family_grid, make_plan
    from uavsim.sim.runner import LoopBatch

    workers, threads = RAW_ARRANGEMENTS[arrangement]
    plan = make_plan(recipe, load_family_grid(recipe))
    order = sorted(range(len(plan.chunks)), key=lambda i: -len(plan.chunks[i]) * plan.durations[i])
    nthread = chunk_threads(len(order), workers) if threads == "split" else [available_cpus()] * len(order)
    batches = []
    for i, nt in zip(order, nthread, strict=True):
        ids = plan.chunks[i]
        params = [replace(plan.grid.params_of(int(plan.class_index[plan.labels[e]])), K=float(plan.K[e]))
                  for e in ids]
        lb = LoopBatch(params, dt=recipe.episodes.dt, rate_hz=recipe.episodes.rate_hz, y0=plan.y0[ids], nthread=nt)
        batches.append((lb, int(round(plan.durations[i] * recipe.episodes.rate_hz))))

    def step(b) -> None:
        lb, T = b
        for _ in range(T):
            lb.batch.step(nstep=lb.rate_steps)

    c0, t0 = time.process_time(), time.perf_counter()
    with cf.ThreadPoolExecutor(max_workers=workers) as ex:
        list(ex.map(step, batches))
    return time.perf_counter() - t0, time.process_time() - c0


def bench_generate(n_classes: int = 26, per_class: int = 16, chunk: int = 104, workers: int | None = None,
                   repeats: int = 2) -> dict:
    """Generate a bench set and step the same batches raw, interleaved ``repeats`` times.

    Each figure is the best (shortest wall) of its repeats: on a machine shared with
    other jobs the best run is the one least disturbed, and interleaving exposes
    generation and raw stepping to the same load.
    """
    from uavsim.data.generate import generate
    from uavsim.data.recipe import parse_recipe
    from uavsim.tuning.grid import load_grid

    g = load_grid("altitude")
    step = max(1, g.n // n_classes)
    classes = list(range(0, g.n, step))[:n_classes]
    text = BENCH_RECIPE.format(classes=classes, per_class=per_class, chunk=chunk)
    walls: dict[str, list[float]] = {a: [] for a in RAW_ARRANGEMENTS}
    cpus: dict[str, list[float]] = {a: [] for a in RAW_ARRANGEMENTS}
    gen, gen_cpu = [], []

    def raw_run(arrangement: str) -> None:
        wall, cpu = _raw_wall(recipe, arrangement)
        walls[arrangement].append(wall)
        cpus[arrangement].append(cpu)

    with tempfile.TemporaryDirectory() as tmp:
        recipe = parse_recipe(text, str(Path(tmp) / "bench.toml"), "bench")
        for k in range(max(1, repeats)):
            raw_run("sequential")
            c0 = time.process_time()
            s = generate(recipe, Path(tmp) / f"bench{k}.h5", workers=workers, progress=False)
            gen_cpu.append(time.process_time() - c0)
            gen.append(s)
            raw_run("concurrent")
            raw_run("split")
    best = min(gen, key=lambda x: x["wall_s"])
    raw_wall = min(min(v) for v in walls.values())  # the fastest arrangement is the baseline
    raw = best["simulated_s"] / raw_wall
    raw_cpu = min(min(v) for v in cpus.values())
    return {"episodes": best["episodes_run"], "classes": len(classes), "repeats": len(gen),
            "simulated_s": best["simulated_s"], "wall_s": best["wall_s"], "wall_s_all": [x["wall_s"] for x in gen],
            "episodes_per_s": best["episodes_per_s"], "sim_s_per_wall_s": best["sim_s_per_wall_s"],
            "raw_wall_s": raw_wall, **{f"raw_{a}_wall_s": v for a, v in walls.items()},
            "raw_sim_s_per_wall_s": raw, "ratio_to_raw": best["sim_s_per_wall_s"] / raw,
            "gen_cpu_s": min(gen_cpu), "gen_cpu_s_all": gen_cpu, "raw_cpu_s": raw_cpu,
            **{f"raw_{a}_cpu_s": v for a, v in cpus.items()}, "cpu_ratio_to_raw": raw_cpu / min(gen_cpu),
            "n_kept": best["n_kept"], "n_rejected": best["n_rejected"], "n_diverged": best["n_diverged"]}


def _run(args: argparse.Namespace) -> int:
    eprint(f"bench generate: {args.classes} altitude classes x {args.per_class} episodes ...")
    r = bench_generate(args.classes, args.per_class, args.chunk, args.workers, args.repeats)
    print_result(r, args.json)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("generate", help="dataset generation vs raw MuJoCo stepping", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--classes", type=int, default=26, help="altitude classes (spread over the grid)")
    p.add_argument("--per-class", dest="per_class", type=int, default=16)
    p.add_argument("--chunk", type=int, default=104, help="episodes per batch")
    p.add_argument("--workers", type=int, default=None, help="threads of the generation backend")
    p.add_argument("--repeats", type=int, default=2, help="interleaved repeats; the best of each is reported")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_run)
