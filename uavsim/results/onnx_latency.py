"""The onnxruntime row of docs/results/io.md: one forward of an exported network, onnxruntime against numpy.

An exported network folder (``uavsim train`` writes ``model.onnx`` and ``weights.npz``
beside ``meta.json``) runs one seeded random input through onnxruntime (one intra-op
thread) and through ``uavsim.learning.export.Predictor`` (numpy, the path identification
takes); each is timed ``--n`` times and the medians are printed with the largest
difference between the two outputs. Run it with one BLAS thread, as identification on a
flight computer would:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m uavsim.results.onnx_latency training/runs/small
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from uavsim.errors import UserError


def _median_ms(f, n: int) -> float:
    t = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        t.append(time.perf_counter() - t0)
    return float(1e3 * np.median(t))


def onnx_latency(model_dir: str | Path, *, n: int = 500, seed: int = 0) -> dict:
    """Median ms of one forward with onnxruntime and with numpy, and their largest output difference."""
    from uavsim.learning.export import Predictor

    d = Path(model_dir)
    if not (d / "model.onnx").is_file():
        raise UserError(f"{d}: no model.onnx (a folder written by `uavsim train`)")
    try:
        import onnxruntime as ort
    except ImportError:
        raise UserError("onnxruntime is not installed: pip install onnxruntime") from None
    p = Predictor(d)
    o = ort.SessionOptions()
    o.intra_op_num_threads = 1
    s = ort.InferenceSession(str(d / "model.onnx"), o)
    name = s.get_inputs()[0].name
    x = np.random.default_rng(seed).standard_normal((1, p.channels, p.input_length)).astype(np.float32)
    ort_ms = _median_ms(lambda: s.run(None, {name: x}), n)
    np_ms = _median_ms(lambda: p.activations(x), n)
    diff = float(np.abs(s.run(None, {name: x})[0] - p.activations(x)).max())
    return {"model": str(d), "n": n, "seed": seed, "onnxruntime_ms": ort_ms, "numpy_ms": np_ms, "max_diff": diff}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uavsim.results.onnx_latency", description=__doc__.split("\n\n")[0])
    ap.add_argument("model", help="an exported network folder (model.onnx, weights.npz, meta.json)")
    ap.add_argument("--n", type=int, default=500, help="timed calls of each (default 500)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the random input (default 0)")
    args = ap.parse_args(argv)
    prog = "python -m uavsim.results.onnx_latency"
    if args.n < 1:
        print(f"{prog}: --n must be >= 1, got {args.n}", file=sys.stderr)
        return 2
    try:
        print(json.dumps(onnx_latency(args.model, n=args.n, seed=args.seed), indent=1))
    except UserError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
