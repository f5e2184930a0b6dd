"""`fovjax` command line. Each subcommand lives next to the code it drives and registers itself
through a `register(subparsers)` function listed in `_SUBCOMMAND_MODULES`."""

from __future__ import annotations

import argparse
import importlib
import sys

# Modules that define `register(subparsers)`. The first one's command is the default
# when `fovjax` is run with no arguments.
_SUBCOMMAND_MODULES = [
    "fovjax._cli_render",
    "fovjax.devices._cli",
    "fovjax._cli_session",
    "fovjax.eval._cli",
    "fovjax.eval._cli_failures",
    "fovjax.eval._cli_study",
    "fovjax.acuity._cli",
    "fovjax.view._cli",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fovjax", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _SUBCOMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if not argv and _SUBCOMMAND_MODULES:
        argv = [next(iter(parser._subparsers._group_actions[0].choices))]
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
