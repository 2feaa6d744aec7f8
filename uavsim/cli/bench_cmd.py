"""``uavsim bench ...``: benchmarks that print a table (or JSON with ``--json``)."""

from __future__ import annotations

import argparse
import importlib

_BENCHES = ["uavsim.bench.sim", "uavsim.bench.noise"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmarks (ratios against a same-run baseline)", description=__doc__)
    bsub = p.add_subparsers(dest="bench_command", metavar="BENCH")
    bsub.required = True
    for name in _BENCHES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue
        mod.register(bsub)
