"""The ``uavsim`` command line: one module per subcommand, each with ``register(subparsers)``.

``uavsim.cli.main`` builds the parser from ``COMMANDS`` and imports only the
module of the command being run; ``uavsim.cli._common`` holds the shared
printing helpers. Every ``UserError`` becomes one line on stderr and exit 2.

    uavsim --help
    uavsim generate datasets/small.toml --out datasets/small.h5
"""
