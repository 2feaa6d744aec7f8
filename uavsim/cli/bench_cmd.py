"""``uavsim bench ...``: benchmarks that print a table (or JSON with ``--json``)."""

from __future__ import annotations

import argparse

from uavsim.cli._common import register_modules

_BENCHES = [
    "uavsim.bench.sim",
    "uavsim.bench.noise",
    "uavsim.bench.generate",
    "uavsim.bench.infer",
    "uavsim.bench.gap",
]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmarks (ratios against a same-run baseline)", description=__doc__)
    bsub = p.add_subparsers(dest="bench_command", metavar="BENCH")
    bsub.required = True
    register_modules(bsub, _BENCHES)
