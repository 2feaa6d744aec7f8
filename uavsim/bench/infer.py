"""Benchmark: identification latency (``uavsim bench infer``).

One identification is what ``uavsim identify`` does after reading the session,
on the table path (``uavsim.ident``): the cycle's extraction and checks
(``extract_cycle``: edges, last cycle, normalization, fundamental response),
the exported network (``Predictor``: the folded weights of ``weights.npz`` run
as a numpy matmul chain, no torch) on one input (on each steady cycle, their beliefs
combined, for a loop whose ``IDENT_INPUTS`` say ``each``: ``cycle_activations``), the model fit and the
table's gains (``identify_cycle``). The goal is on that whole identification on
the table path (``identification_table_path``: the grid's Bayes decision,
``identify --decision bayes --no-guard``; <= 2 ms median on one thread). ``identification``
is the same with the loop's defaults (the inner loops' ``blend`` closes the belief's fitted
models and the phase-margin guard its answer's, a few ms more, for a lower J:
docs/results/identification.md); its stages are reported beside them, with
``identification_guarded`` (the whole identification with the guard, ``identify --guard``)
``identification_two_points`` (the loop's defaults with a second run at ``SECOND_BETA``, its cycle's
extraction included, and where the model folder has a second network beside it, ``uavsim.ident.secondnet``,
that network's read of the run: what ``uavsim identify`` does on a session that holds one) and the opt-in optimum
of the fitted model (``--optimum``, ``fitted_optimum``). Each is timed ``--reps`` times on a 10 s,
200 Hz NP-MRFT trace of a mid-grid altitude process (exact lumped simulation
with 5% white noise), with torch on ``--threads`` threads (1: the embedded case).
The network's first layer multiplies only the input's samples of the cycle (inputs are
right-aligned and zero-padded), so its cost grows with the cycle's length:
``identification_table_path_slowest_class`` is the table path on a 20 s trace of the
grid's slowest class, whose cycle fills the input.

The same-run baseline is a bare numpy float32 forward pass of the same layer
sizes (three matmuls and two ReLUs, no BatchNorm, no bias, no period
features): the floor an implementation of this network can reach on this
machine; the network stage is that plus the period features and biases. The table gives median and p95 (ms)
of each stage and the ratio of the table path to the baseline,
and ``onnxruntime_network``: the same network from ``model.onnx`` on onnxruntime
with ``--threads`` threads (when onnxruntime is installed).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 uavsim bench infer --json
    uavsim bench infer --models training/runs/altitude --reps 500

Run it with one BLAS/OpenMP thread as above: on a shared 2-core machine the
default thread pools of numpy and torch oversubscribe the cores and the
medians become 10-30x worse (measured), which says nothing about the method.

Without a trained altitude network (``training/runs/altitude``) a randomly
initialized network of the same shape is exported to a temporary folder:
latency does not depend on the weights.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

GOAL_MS = 2.0


def _trace(grid, c: int, seconds: float = 10.0, seed: int = 0, beta: float | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
    from uavsim.lumped.simulate import simulate_relay_batch

    p = grid.params_of(c)
    b = grid.beta if beta is None else beta
    sim = simulate_relay_batch("altitude", b, 1.0, 0.005, int(seconds * 200), K=1.0, T_prop=p.T_prop, T1=p.T1,
                               tau=p.tau)
    rng = np.random.default_rng(seed)
    y = -sim["e"][0] + 0.05 * grid.amplitude[c] * rng.standard_normal(sim["e"].shape[1])
    return y, sim["u"][0]


def _stats(t: np.ndarray) -> dict[str, float]:
    return {"median_ms": float(np.median(t) * 1e3), "p95_ms": float(np.percentile(t, 95) * 1e3)}


def _model_dir(arg: str | None, tmp: Path) -> tuple[Path, bool]:
    from uavsim.ident.bundle import default_model_root

    if arg:
        return Path(arg), True
    d = default_model_root() / "altitude"
    if (d / "meta.json").is_file():
        return d, True
    import torch

    from uavsim.data.generate import class_table_gains
    from uavsim.data.preprocess import input_length
    from uavsim.learning.bundle import bundle_section
    from uavsim.learning.export import export_model
    from uavsim.learning.model import IdentNet, NetConfig
    from uavsim.tuning.grid import load_grid

    g = load_grid("altitude")
    torch.manual_seed(0)
    cfg = NetConfig(2, input_length(g), g.n)
    classes = {k: np.asarray(getattr(g, k)).tolist() for k in ("kp", "kd", "derivative_filter_hz", "amplitude",
                                                                "period")}
    classes.update({k: np.asarray(g.params[k]).tolist() for k in ("T_prop", "T1", "tau")})
    classes.update({k: np.asarray(v).tolist() for k, v in class_table_gains("altitude", 200.0, None).items()
                    if k != "J"})
    meta = {"loop": "altitude", "grid_hash": g.hash, "beta": g.beta, "pm_deg": g.pm_deg, "channels": 2,
            "input_length": cfg.input_length, "n_classes": g.n, "cycles": 1, "classes": classes,
            "identification": bundle_section(loop="altitude", grid_hash=g.hash, rate_hz=200.0, beta=g.beta,
                                             input_length=cfg.input_length, cycles=1)}
    export_model(IdentNet(cfg).eval(), meta, tmp)
    return tmp, False


def run_bench(models: str | None = None, reps: int = 300, threads: int = 1) -> dict[str, Any]:
    """Time preprocessing, network and whole identification; see module docstring."""
    import torch

    from uavsim.ident.bundle import load_bundle
    from uavsim.ident.cycle import extract_cycle
    from uavsim.ident.gains import fitted_model, model_optimum, table_gains
    from uavsim.ident.secondnet import load_second_bundle, second_reading
    from uavsim.ident.select import DEFAULT_DECISION, choose_class, cycle_activations
    from uavsim.ident.session import identify_arrays, second_cycle
    from uavsim.ident.twopoint import SECOND_BETA
    from uavsim.tuning.grid import load_grid

    g = load_grid("altitude")
    c = int(np.argsort(g.period)[g.n // 2])
    y, u = _trace(g, c)
    # the longest cycle fills the whole input: the network's first layer at its largest (the goal is on
    # the mid-grid trace; this row shows the worst case beside it)
    y_slow, u_slow = _trace(g, int(np.argmax(g.period)), seconds=20.0)
    # the same process's second run at SECOND_BETA (slower: twice as long), the same sensor noise
    y2, u2 = _trace(g, c, seconds=20.0, seed=1, beta=SECOND_BETA)
    with tempfile.TemporaryDirectory() as tmp:
        d, trained = _model_dir(models, Path(tmp))
        b = load_bundle(d)
        b2 = load_second_bundle(d, b) if trained else None
        pred = b.predictor
        if threads is not None:
            torch.set_num_threads(int(threads))
        L = pred.input_length
        W = [_input_major(m) for m in _linear_layers(pred)] if hasattr(pred.module, "layers") else None
        kw = {"rate_hz": 200.0, "h": 1.0, "bias": 0.0, "bundle": b}
        table_decision = "bayes" if b.cost is not None else "argmax"  # a bundle without J decides by argmax
        x0 = extract_cycle(y, u, **kw).x
        for _ in range(20):  # warm-up (caches)
            identify_arrays(y, u, beta=g.beta, **kw)
        t_pre, t_net, t_all, t_base, t_opt, t_grd, t_tab, t_slow, t_two = (np.empty(reps) for _ in range(9))
        f = extract_cycle(y, u, **kw)
        c = choose_class(b, pred.activations(f.x), decision=b.decision)  # the optimum's start: the grid's class
        model = fitted_model(b, c, np.array([f.response]), np.array([f.response_period]))
        start = table_gains(b, c, model["K"])
        xb = x0.reshape(1, -1).astype(np.float32)
        if W is not None and W[0].shape[0] != xb.shape[1]:  # period features widen the first layer
            xb = np.concatenate([xb, np.zeros((1, W[0].shape[0] - xb.shape[1]), np.float32)], axis=1)
        for i in range(reps):
            t0 = time.perf_counter()
            f = extract_cycle(y, u, **kw)
            t1 = time.perf_counter()
            cycle_activations(b, f)
            t2 = time.perf_counter()
            identify_arrays(y, u, beta=g.beta, **kw)
            t3 = time.perf_counter()
            if W is not None:
                h = xb
                for j, w in enumerate(W):
                    h = h @ w
                    if j < len(W) - 1:
                        np.maximum(h, 0.0, out=h)
            t4 = time.perf_counter()
            identify_arrays(y, u, beta=g.beta, guard=True, **kw)
            t5 = time.perf_counter()
            identify_arrays(y, u, beta=g.beta, decision=table_decision, guard=False, **kw)
            t6 = time.perf_counter()
            identify_arrays(y_slow, u_slow, beta=g.beta, decision=table_decision, guard=False, **kw)
            t7 = time.perf_counter()
            f2 = second_cycle(y2, u2, rate_hz=200.0, h=1.0, bias=0.0, cycles=b.cycles, loop=b.loop)
            r2 = None if b2 is None else second_reading(b2, y2, u2, rate_hz=200.0, h=1.0, bias=0.0)
            identify_arrays(y, u, beta=g.beta, second=f2, second_network=r2, **kw)
            t8 = time.perf_counter()
            t_pre[i], t_net[i], t_all[i], t_base[i], t_grd[i] = t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4
            t_tab[i], t_slow[i], t_two[i] = t6 - t5, t7 - t6, t8 - t7
        for i in range(max(1, reps // 10)):  # the optional optimum: 10-20 ms each
            t0 = time.perf_counter()
            model_optimum(b, model, start=start)
            t_opt[i] = time.perf_counter() - t0
        t_opt = t_opt[: max(1, reps // 10)]
        onnx = _onnx_stats(d, x0, reps, threads)
    out = {
        "trained_model": trained, "model_dir": str(d) if trained else "(random weights, same shape)",
        "input": [pred.channels, L], "n_classes": pred.n_classes, "threads": torch.get_num_threads(), "reps": reps,
        "preprocess": _stats(t_pre), "network": _stats(t_net), "preprocess_plus_network": _stats(t_pre + t_net),
        "identification": _stats(t_all), "identification_table_path": _stats(t_tab),
        "identification_table_path_slowest_class": _stats(t_slow),
        "default_decision": DEFAULT_DECISION.get("altitude", b.decision),
        "identification_guarded": _stats(t_grd), "identification_two_points": _stats(t_two),
        "second_network": None if b2 is None else str(b2.dir),
        "fitted_optimum": _stats(t_opt),
        "baseline_numpy_forward": _stats(t_base) if W is not None else None, "goal_ms": GOAL_MS,
        "blas_threads_env": {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")},
    }
    if W is not None:
        base = out["baseline_numpy_forward"]["median_ms"]
        out["ratio_identification_to_baseline"] = out["identification"]["median_ms"] / base
        out["ratio_table_path_to_baseline"] = out["identification_table_path"]["median_ms"] / base
    out["meets_goal"] = out["identification_table_path"]["median_ms"] <= GOAL_MS
    out["onnxruntime_network"] = onnx
    return out


def _onnx_stats(d: Path, x0: np.ndarray, reps: int, threads: int) -> dict[str, float] | None:
    """The same forward pass on ``model.onnx`` with onnxruntime on ``threads`` threads (None without either)."""
    if not (d / "model.onnx").is_file():
        return None
    try:
        import onnxruntime as ort
    except ImportError:
        return None
    so = ort.SessionOptions()
    so.intra_op_num_threads = so.inter_op_num_threads = max(1, int(threads))
    sess = ort.InferenceSession(str(d / "model.onnx"), so, providers=["CPUExecutionProvider"])
    x = np.ascontiguousarray(x0[None], dtype=np.float32)
    for _ in range(20):
        sess.run(None, {"x": x})
    t = np.empty(reps)
    for i in range(reps):
        t0 = time.perf_counter()
        sess.run(None, {"x": x})
        t[i] = time.perf_counter() - t0
    return _stats(t)


def _linear_layers(pred) -> list:
    """Linear layers of the scripted network, in order (for the numpy baseline's sizes and weights)."""
    import torch

    mods = []
    for m in pred.module.layers.children():
        if isinstance(m, torch.jit.RecursiveScriptModule) and m.original_name in ("Linear", "InputMajorLinear"):
            mods.append(m)
    return mods


def _input_major(m) -> np.ndarray:
    """A linear layer's weight as (in, out) float32 (nn.Linear stores (out, in))."""
    if hasattr(m, "weight_t"):
        return np.ascontiguousarray(m.weight_t.detach().numpy())
    return np.ascontiguousarray(m.weight.detach().numpy().T)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("infer", help="identification latency on the table path, vs a numpy forward pass",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--models", help="exported model folder (default: training/runs/altitude, else random weights)")
    p.add_argument("--reps", type=int, default=300)
    p.add_argument("--threads", type=int, default=1, help="torch threads (1: the embedded case)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from uavsim.cli._common import print_json, print_table
    from uavsim.errors import UserError

    if args.reps < 1 or args.threads < 1:
        raise UserError("--reps and --threads must be >= 1")
    out = run_bench(args.models, args.reps, args.threads)
    if args.json:
        print_json(out)
        return 0
    rows = []
    for k in ("preprocess", "network", "preprocess_plus_network", "identification_table_path",
              "identification_table_path_slowest_class", "identification",
              "identification_guarded", "identification_two_points", "fitted_optimum", "baseline_numpy_forward"):
        if out.get(k):
            rows.append({"stage": k, **out[k]})
    print_table(rows)
    print(f"input {out['input']}, {out['n_classes']} classes, {out['threads']} thread(s), {out['model_dir']}; "
          f"table path / numpy forward = {out.get('ratio_table_path_to_baseline', float('nan')):.2f}; "
          f"goal (identification_table_path) <= {GOAL_MS} ms: {'met' if out['meets_goal'] else 'MISSED'}; "
          f"the default decision ({out['default_decision']}) takes {out['identification']['median_ms']:.2f} ms")
    if out.get("second_network"):
        print(f"identification_two_points includes the second run's network {out['second_network']}")
    return 0
