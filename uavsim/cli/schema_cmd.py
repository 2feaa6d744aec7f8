"""``uavsim schema KIND``: the JSON Schema of a TOML file kind, for editors and other tools.

Kinds: ``session`` (a session's session.toml), ``dataset`` (datasets/*.toml),
``training`` (training/*.toml), ``scenario`` (scenarios/*.toml) and
``gap-model`` (``uavsim gap --model FILE``). ``--check FILE`` validates a file
against it instead (one line naming the file, key and problem; exit 2).

    uavsim schema training > training.schema.json
    uavsim schema dataset --check datasets/small.toml
"""

from __future__ import annotations

import argparse
import json

from uavsim.schema import KINDS


def register(subparsers) -> None:
    p = subparsers.add_parser("schema", help="JSON Schema of a TOML file kind", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("kind", choices=list(KINDS), help="file kind")
    p.add_argument("--check", metavar="FILE", help="validate FILE against the schema instead of printing it")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from uavsim.schema import json_schema, load_toml

    if args.check:
        load_toml(args.check, args.kind)
        print(f"{args.check}: valid {args.kind} file")
        return 0
    print(json.dumps(json_schema(args.kind), indent=1))
    return 0
