"""``python -m autotune.train``: a thin shim for ``autotune train`` (see ``autotune.commands.train``)."""

from __future__ import annotations

import sys

from autotune import cli


def main(argv: list[str] | None = None) -> int:
    """``autotune train ARGV…``; returns the exit status."""
    return cli.main(["train", *(sys.argv[1:] if argv is None else argv)], owns_process=argv is None)


if __name__ == "__main__":
    sys.exit(main())
