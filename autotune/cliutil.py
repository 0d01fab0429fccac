"""What every ``autotune`` subcommand spells the same way: the bad-input exit and the study-storage options.

Bad input (house style): one line ``error: <what>: <problem>`` on stderr, exit status 2, no traceback —
printed by ``autotune.cli.main`` (``fail``) for every ``ConfigError`` a command raises. ``--storage`` is ''
for the study's embedded ``runs/<study>/journal.log``; ``--artifacts`` None for the artifact store beside
the storage. Output destinations (``--out``, ``--export``) are checked with ``output_file`` /
``output_dir`` before a command does any work, so a place it cannot write fails in a line, not after
minutes of work. Imports nothing heavy (stdlib and ``sim.config``'s error type).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from sim.config import ConfigError

__all__ = [
    "EXIT_USAGE",
    "STORAGE_HELP",
    "ARTIFACTS_HELP",
    "fail",
    "add_storage_arguments",
    "output_file",
    "output_dir",
]

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


def output_file(path: str | Path, option: str) -> Path:
    """``path`` checked as a file the command will write (missing directories are made then); creates nothing.

    ``ConfigError`` naming ``option`` when it is a directory, when a directory on its way is a file, or
    when the file or the directory it would be made in is not writable.
    """
    out = Path(path)
    if out.is_dir():
        raise ConfigError(f"{option}: {out} is a directory; name the file to write")
    if out.exists():
        try:
            with out.open("ab"):  # opening for append changes nothing
                pass
        except OSError as exc:
            raise ConfigError(f"{option}: cannot write {out} ({exc.strerror or exc}); choose another file") from None
        return out
    _writable_ancestor(out, option)
    return out


def output_dir(path: str | Path, option: str) -> Path:
    """``path`` checked as a directory the command will write files into (made then if missing); creates nothing.

    ``ConfigError`` naming ``option`` when it, or a directory on its way, is a file, or when it (or the
    directory it would be made in) is not writable.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{option}: {out} is a file, not a directory; name a directory")
    _writable_ancestor(out, option)
    return out


def _writable_ancestor(path: Path, option: str) -> None:
    """Fail unless the nearest existing directory at or above ``path`` is a directory a file can be made in."""
    here = path if path.is_dir() else path.parent
    while not here.exists() and here != here.parent:
        here = here.parent
    if not here.is_dir():
        raise ConfigError(f"{option}: cannot write {path}: {here} is a file, not a directory")
    try:  # a file made and removed at once: what os.access cannot tell (root on a read-only or virtual file system)
        fd, probe = tempfile.mkstemp(prefix=".autotune-write-check-", dir=here)
    except OSError as exc:
        raise ConfigError(
            f"{option}: cannot write {path}: directory {here} is not writable ({exc.strerror or exc}); "
            "choose a writable place"
        ) from None
    os.close(fd)
    os.unlink(probe)
