"""``autotune <subcommand>``: the console script. Command modules parse and print; the work is library code.

Each subcommand lives in its own module under ``autotune/commands/`` exposing
``add_parser(subparsers) -> None`` (adds its subparser with help text and ``func=run``) and
``run(args) -> int``. Adding a subcommand is one line in ``SUBCOMMANDS``. Bad input is one error
type: argparse's complaints and every ``ConfigError`` a command raises (spec, storage, net file,
crowd data, filter, record, …: all subclasses) become one line ``error: …`` on stderr and exit
status 2 here, in ``main`` — and nowhere else.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import NoReturn

from autotune.cliutil import EXIT_USAGE, fail
from sim.config import ConfigError

# one module per subcommand, in the order ``autotune --help`` lists them
SUBCOMMANDS: tuple[str, ...] = (
    "autotune.commands.train",
    "autotune.commands.evaluate",
    "autotune.commands.launch",
    "autotune.commands.inspect",  # status, best, dashboard
    "autotune.commands.crowd",
    "autotune.commands.compare",
    "autotune.commands.replay",
)


class ArgumentParser(argparse.ArgumentParser):
    """argparse with the house error style: one line on stderr, exit status 2, no usage dump."""

    def error(self, message: str) -> NoReturn:
        raise SystemExit(fail(message))


def build_parser() -> argparse.ArgumentParser:
    """The ``autotune`` parser with every subcommand of ``SUBCOMMANDS`` registered."""
    parser = ArgumentParser(prog="autotune", description="DeepTraffic deep-Q-learning: train, evaluate, tune.")
    subparsers = parser.add_subparsers(dest="command", metavar="<command>", required=True)
    for module_name in SUBCOMMANDS:
        importlib.import_module(module_name).add_parser(subparsers)
    return parser


def main(argv: list[str] | None = None, *, owns_process: bool | None = None) -> int:
    """Parse ``argv`` (default ``sys.argv[1:]``) and run the chosen subcommand; returns the exit status.

    As the process's owner (default: when ``argv`` is None, i.e. run as the console script) it
    first sets the process-wide settings (``configure_process``; not for the commands that only read a
    study and draw, whose parsers say ``process_settings=False``: importing torch costs them ~2 s); an
    in-process call (a test, a notebook) leaves its caller's process as it is. A ``ConfigError`` from
    the command is printed as one line (its first) and returns 2.
    """
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0) or a one-line usage error already printed (2)
        return int(exc.code) if isinstance(exc.code, int) else EXIT_USAGE
    owner = argv is None if owns_process is None else owns_process
    if owner and getattr(args, "process_settings", True):  # commands that only read and draw skip torch's import
        from autotune.runtime import configure_process

        configure_process()
    try:
        return int(args.func(args))
    except ConfigError as exc:
        return fail((str(exc).splitlines() or [type(exc).__name__])[0])


if __name__ == "__main__":
    sys.exit(main())
