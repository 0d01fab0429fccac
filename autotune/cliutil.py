"""What every ``autotune`` subcommand spells the same way: the bad-input exit and the study-storage options.

Bad input (house style): one line ``error: <what>: <problem>`` on stderr, exit status 2, no traceback —
printed by ``autotune.cli.main`` (``fail``) for every ``ConfigError`` a command raises. ``--storage`` is ''
for the study's embedded ``runs/<study>/journal.log``; ``--artifacts`` None for the artifact store beside
the storage. Imports nothing heavy (stdlib only).
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["EXIT_USAGE", "STORAGE_HELP", "ARTIFACTS_HELP", "fail", "add_storage_arguments"]

EXIT_USAGE = 2

STORAGE_HELP = "journal file or SQLAlchemy URL (default: runs/<study>/journal.log)"
"""``--storage``'s help where it names a study's storage for its own sake."""
ARTIFACTS_HELP = "artifact directory of the study (default: beside the journal / runs/<study>/)"
"""``--artifacts``'s help where it names a study's artifact store for its own sake."""


def fail(message: str, status: int = EXIT_USAGE) -> int:
    """Print ``error: <message>`` on stderr and return ``status`` (2: bad input) for ``run`` to return."""
    print(f"error: {message}", file=sys.stderr)
    return status


def add_storage_arguments(
    parser: argparse.ArgumentParser,
    *,
    storage_help: str = STORAGE_HELP,
    artifacts_help: str | None = ARTIFACTS_HELP,
) -> None:
    """``--storage URL`` (default '') and, unless ``artifacts_help`` is None, ``--artifacts DIR`` (default None)."""
    parser.add_argument("--storage", default="", help=storage_help)
    if artifacts_help is not None:
        parser.add_argument("--artifacts", help=artifacts_help)
