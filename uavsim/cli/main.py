"""The ``uavsim`` command: one CLI, one subcommand per job.

Each subcommand lives in its own module under ``uavsim.cli`` (or
``uavsim.bench`` for benchmarks) and exposes ``register(subparsers)``, which
adds its parser and sets ``func(args) -> int``. User errors
(``uavsim.errors.UserError``) print one line on stderr and exit with 2.

    uavsim --help
    uavsim model export --out hexarotor.xml
"""

from __future__ import annotations

import argparse
import os
import sys

from uavsim.cli._common import register_modules
from uavsim.errors import UserError

# Modules that register subcommands, in --help order.
_COMMAND_MODULES = [
    "uavsim.cli.model_cmd",
    "uavsim.cli.sim_cmd",
    "uavsim.cli.session_cmd",
    "uavsim.cli.tune_cmd",
    "uavsim.cli.grid_cmd",
    "uavsim.cli.noise_cmd",
    "uavsim.cli.generate_cmd",
    "uavsim.cli.train_cmd",
    "uavsim.cli.identify_cmd",
    "uavsim.cli.scenario_cmd",
    "uavsim.cli.gap_cmd",
    "uavsim.cli.testbed_cmd",
    "uavsim.cli.replay_cmd",
    "uavsim.cli.bench_cmd",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uavsim",
        description="Identify and tune multirotor loops with DNN-NP-MRFT on a MuJoCo hexarotor.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    register_modules(sub, _COMMAND_MODULES)
    return parser


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"uavsim {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"uavsim {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
