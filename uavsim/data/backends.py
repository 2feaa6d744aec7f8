"""Where the chunks of a plan run, and how a run survives interruption.

``run_threads`` (a local thread pool) and ``run_dask`` (Dask distributed tasks)
run the chunks and hand each result to a callback; :class:`ResumeState` saves
finished chunks atomically under ``OUT.resume/`` so that a run continues where
it stopped; :class:`Progress` reports; the versions and commit that shape the
data are recorded with it.

    state = ResumeState(out, plan)
    run_threads(plan, [i for i in range(len(plan.chunks)) if i not in state.done()], 2, state.save)
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from uavsim.control.relay import READING, TRIM_RULE
from uavsim.cpus import available_cpus
from uavsim.data.episodes import chunk_task, run_chunk
from uavsim.data.h5 import FORMAT, open_dataset
from uavsim.data.plan import Plan
from uavsim.errors import UserError
from uavsim.noise.estimate import SETTINGS_RULE

# --- resume state ---------------------------------------------------------------------------------

def finished_file(out: Path, plan: Plan) -> bool:
    """Whether ``out`` is already the complete file of ``plan``: a lateral run (one file per
    attitude class) interrupted after some files continues without making them again.

    The file must pass ``open_dataset``'s checks (format, complete, its arrays), and its key
    must be the chunks' resume key (recipe, attitude class, relay reading, settings and trim rules) and
    the grid the file was made over; a file of another recipe, grid, reading or rule is made again.
    """
    if not out.exists():
        return False
    try:
        a = open_dataset(out).attrs
    except UserError:
        return False
    att = a.get("att_class")
    return (a.get("recipe") == plan.recipe.text and int(a.get("seed", -1)) == plan.recipe.seed
            and a.get("grid_hash") == (plan.grid.hash or "") and a.get("relay_reading") == READING
            and int(a.get("settings_rule", 1)) == SETTINGS_RULE
            and int(a.get("trim_rule", 1)) == TRIM_RULE
            and (None if att is None else int(att)) == plan.att_class)


class ResumeState:
    """Finished chunks of one output file, saved atomically under ``OUT.resume/``."""

    def __init__(self, out: Path, plan: Plan):
        self.dir = out.with_name(out.name + ".resume")
        self.key = {"recipe_hash": plan.recipe.hash, "att_class": plan.att_class, "n_chunks": len(plan.chunks),
                    "format": FORMAT, "relay_reading": READING,
                    "settings_rule": SETTINGS_RULE, "trim_rule": TRIM_RULE}
        state = self.dir / "state.json"
        if self.dir.exists():
            try:
                old = json.loads(state.read_text())
            except (OSError, ValueError):
                old = None
            if old != self.key:
                print(f"generate: {self.dir} is from another recipe, relay reading, settings rule or trim rule; starting over", file=sys.stderr, flush=True)
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


class Progress:
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

def dask_client(backend: str):
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


def chunk_threads(n: int, workers: int, cpus: int | None = None) -> list[int]:
    """Physics threads of each of ``n`` chunks run ``workers`` at a time, in order.

    Each chunk gets its share of the CPUs (``cpus // workers``, at least 1), so that
    chunks running together do not oversubscribe the cores: a batch's step waits for
    all its threads, and one thread descheduled by the other chunk's holds it back.
    One chunk's numpy controller then runs while the other's physics does. The last
    chunk gets every CPU, since it finishes alone.
    """
    cpus = cpus or available_cpus()
    share = max(1, cpus // max(1, workers))
    return [share] * max(0, n - 1) + [cpus] * min(1, n)


def run_threads(plan: Plan, todo: list[int], workers: int, on_result: Callable[[int, dict], None]) -> None:
    """Run chunks ``todo`` (in that order) ``workers`` at a time, each on its ``chunk_threads``."""
    workers = max(1, min(workers, len(todo))) if todo else 1
    ex = cf.ThreadPoolExecutor(max_workers=workers)
    try:
        futs = {ex.submit(run_chunk, plan, i, nt): i for i, nt in zip(todo, chunk_threads(len(todo), workers), strict=True)}
        for f in cf.as_completed(futs):
            on_result(futs[f], f.result())
    finally:
        ex.shutdown(wait=False, cancel_futures=True)


def run_dask(plan: Plan, todo: list[int], client, on_result: Callable[[int, dict], None]) -> None:
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
    """Versions of what shapes the data (stored in the file as JSON).

    ``blas`` names the BLAS libraries and the kernels they chose for this CPU
    (``OPENBLAS_CORETYPE`` overrides OpenBLAS's choice): another kernel moves the
    samples' last bits, so it tells why one recipe and seed gave other bytes elsewhere.
    """
    import h5py
    import mujoco

    import uavsim

    return {"python": sys.version.split()[0], "numpy": np.__version__, "mujoco": mujoco.__version__,
            "h5py": h5py.__version__, "uavsim": getattr(uavsim, "__version__", "unknown"),
            "blas": blas_kernels(with_version=True)}


def blas_kernels(*, with_version: bool = False) -> str:
    """The BLAS libraries numpy and scipy loaded and the kernels they run, e.g. ``"openblas Haswell"``
    (``"openblas 0.3.31 Haswell"`` with their versions), one entry per distinct library."""
    import scipy.linalg  # noqa: F401 - loads scipy's own BLAS, so that it is listed too
    from threadpoolctl import threadpool_info

    kinds = sorted({" ".join([str(i.get("internal_api"))] + ([str(i.get("version"))] if with_version else [])
                             + [str(i.get("architecture", "?"))])
                    for i in threadpool_info() if i.get("user_api") == "blas"})  # fmt: skip
    return ", ".join(kinds) or "none"


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
