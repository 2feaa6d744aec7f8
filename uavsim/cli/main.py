"""The ``uavsim`` command: one CLI, one subcommand per job.

Each subcommand lives in its own module under ``uavsim.cli`` (or
``uavsim.bench`` for benchmarks) and exposes ``register(subparsers)``, which
adds its parser and sets ``func(args) -> int``. Only the module of the command
being run is imported (``uavsim --help`` lists the others from ``COMMANDS``,
without importing numpy, scipy or MuJoCo). User errors
(``uavsim.errors.UserError``) print one line on stderr and exit with 2.

    uavsim --help
    uavsim --version
    uavsim model export --out hexarotor.xml
    python -m uavsim --help
"""

from __future__ import annotations

import argparse
import os
import sys

from uavsim import __version__
from uavsim.cli._common import register_modules
from uavsim.errors import UserError

#: command name -> (module that registers it, one-line help for ``uavsim --help``), in --help order
COMMANDS: dict[str, tuple[str, str]] = {
    "model": ("uavsim.cli.model_cmd", "the hexarotor model"),
    "sim": ("uavsim.cli.sim_cmd", "simulate loops of the hexarotor"),
    "session": ("uavsim.cli.session_cmd", "inspect flight sessions and import flight logs"),
    "tune": ("uavsim.cli.tune_cmd", "PD gains of the MRFT tuning rule for a lumped process (K = 1)"),
    "grid": ("uavsim.cli.grid_cmd", "build or report the lumped-model class grids"),
    "noise": ("uavsim.cli.noise_cmd", "estimate measurement noise and recommend NP-MRFT tau_obs and a_n"),
    "generate": ("uavsim.cli.generate_cmd", "build a training set from a recipe (datasets/*.toml)"),
    "train": ("uavsim.cli.train_cmd", "train DNN-NP-MRFT networks from a recipe (training/*.toml)"),
    "identify": ("uavsim.cli.identify_cmd", "identify a loop from a session's NP-MRFT run (DNN-NP-MRFT)"),
    "evaluate": ("uavsim.cli.evaluate_cmd", "identification on off-grid processes: J against each process's optimum"),
    "export-gains": ("uavsim.cli.export_gains_cmd", "write identified gains as PX4 or ArduPilot parameters"),
    "scenario": ("uavsim.cli.scenario_cmd", "visual-servoing scenarios (identify, tune, test)"),
    "gap": ("uavsim.cli.gap_cmd", "sim-vs-measured gap: name the effect the model lacks"),
    "testbed": ("uavsim.cli.testbed_cmd", "measured sessions from a richer vehicle with hidden effects"),
    "replay": ("uavsim.cli.replay_cmd", "Rerun recording of a session, dataset episode or scenario"),
    "schema": ("uavsim.cli.schema_cmd", "JSON Schema of a TOML file kind (session, dataset, training, ...)"),
    "bench": ("uavsim.cli.bench_cmd", "benchmarks (ratios against a same-run baseline)"),
}

# Modules that register subcommands, in --help order (tests narrow it to one module).
_COMMAND_MODULES = [mod for mod, _ in COMMANDS.values()]


def _chosen(argv: list[str]) -> str | None:
    """The command named on the command line (the first word that is not an option)."""
    for a in argv:
        if not a.startswith("-"):
            return a
    return None


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser; the command named in ``argv`` gets its full parser, the others a stub for --help.

    ``argv=None`` registers every command fully (imports them all).
    """
    parser = argparse.ArgumentParser(
        prog="uavsim",
        description="Identify and tune multirotor loops with DNN-NP-MRFT on a MuJoCo hexarotor.",
    )
    parser.add_argument("--version", action="version", version=f"uavsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    chosen = _chosen(argv) if argv is not None else None
    by_module = {mod: (name, text) for name, (mod, text) in COMMANDS.items()}
    for mod_name in _COMMAND_MODULES:
        name, text = by_module.get(mod_name, (mod_name.rsplit(".", 1)[-1].removesuffix("_cmd"), ""))
        if argv is not None and name != chosen:
            sub.add_parser(name, help=text, add_help=False)
        else:
            register_modules(sub, [mod_name])
    return parser


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
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
