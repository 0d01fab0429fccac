"""``python -m autotune.evaluate``: a thin shim for ``autotune evaluate`` (see ``autotune.commands.evaluate``)."""

from __future__ import annotations

import sys

from autotune import cli


def main(argv: list[str] | None = None) -> int:
    """``autotune evaluate ARGV…``; returns the exit status."""
    return cli.main(["evaluate", *(sys.argv[1:] if argv is None else argv)], owns_process=argv is None)


if __name__ == "__main__":
    sys.exit(main())
