"""``autotune launch``: run (or resume) a study of a TOML spec on a local Ray pool or a Ray cluster.

    autotune launch CONFIG [--storage URL] [--study-name NAME] [--workers N] [--n-trials N] [--timeout S]
                           [--warm-start crowd|STUDY] [--address RAY_ADDRESS] [--artifacts DIR] [--quiet]

Creates the study or resumes it (same name and storage: trials left RUNNING by a dead driver are
failed and retried, finished ones kept, only the rest of ``n_trials`` runs). A progress bar on
stderr shows trials finished / pruned / failed, the best score so far, elapsed time and ETA; at
the end the best trial and how to open optuna-dashboard on the study are printed. Exit status 0
once the budget (``n_trials`` / ``timeout_s``) is spent; bad input (a spec error, an unreachable
storage or Ray address) prints one line on stderr and exits with 2 before any worker starts.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from typing import Any

from sim.config import ConfigError

EXIT_INTERRUPTED = 130


def add_parser(subparsers: Any) -> None:
    """``autotune launch``: its options, help text and ``func=run``."""
    p = subparsers.add_parser(
        "launch",
        help="run or resume an Optuna study of a spec on Ray workers",
        description="Run (or resume) the Optuna study of a TOML spec: long-lived Ray workers train and score "
        "the trials, Optuna samples and prunes. Local Ray by default; --address joins a cluster.",
    )
    p.add_argument(
        "config", metavar="CONFIG", help="study spec (TOML: [study] [fixed] [space] [evaluation] [resources])"
    )
    p.add_argument("--storage", help="journal file (*.log) or SQLAlchemy URL (default: [study] storage, else "
                   "runs/<study>/journal.log)")  # fmt: skip
    p.add_argument("--study-name", help="study name (default: [study] name)")
    p.add_argument("--workers", type=int, help="parallel workers (default: [resources] workers)")
    p.add_argument("--n-trials", type=int, help="trials in the study (default: [study] n_trials)")
    p.add_argument(
        "--timeout", type=float, metavar="S", help="stop starting trials after S seconds ([study] timeout_s)"
    )
    p.add_argument("--warm-start", metavar="crowd|STUDY", help="crowd: enqueue the shipped crowd settings of the "
                   "study's engine first (each trained and measured); STUDY: copy that study's measured trials "
                   "into the sampler's history ([warm_start] in the spec)")  # fmt: skip
    p.add_argument("--address", metavar="RAY_ADDRESS", help="join this Ray cluster (host:port) instead of local Ray")
    p.add_argument(
        "--artifacts", metavar="DIR", help="artifact directory (default: beside the journal / runs/<study>/)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Validate everything, run the study, print the best trial; 0, or 130 (Ctrl-C); bad input raises ConfigError."""
    from autotune.search import space
    from autotune.search.driver import Driver, StudyCounts, WarmConfig
    from autotune.search.spec import load_spec
    from autotune.search.storage import open_storage

    spec = load_spec(args.config).with_overrides(
        storage=args.storage, name=args.study_name, workers=args.workers, n_trials=args.n_trials,
        timeout_s=args.timeout, warm_start=args.warm_start,
    )  # fmt: skip
    space.check(spec)  # the space's corners build valid configurations
    storages = open_storage(spec.study.storage, spec.study.name, artifacts=args.artifacts)
    if args.address is not None:
        _check_address(args.address)
    warm: tuple[WarmConfig, ...] = ()
    if spec.warm_start.crowd:
        from dashboards.crowd_prior import prior_settings

        warm = tuple(WarmConfig(p.source, p.config) for p in prior_settings(spec.ruleset))
    driver = Driver(spec, storages, address=args.address, warm_configs=warm)
    driver.open_study()  # create or resume; the sampler is built here (a missing package fails now)

    bar = None if args.quiet else _Bar(spec.study.name, spec.study.n_trials, spec.study.timeout_s)
    driver.on_warm_start = None if args.quiet else _print_warm_notes
    driver.progress = bar.update if bar else None
    try:
        counts: StudyCounts = driver.run()
    except KeyboardInterrupt:
        print("interrupted: running trials failed (retryable); rerun the same command to resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    except ConnectionError as exc:  # a Ray address that does not answer
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"--address {args.address}: cannot join the Ray cluster ({first})") from None
    finally:
        if bar is not None:
            bar.close()
    _print_summary(spec.study.name, storages, counts, driver)
    return 0


def _print_warm_notes(notes: list[str]) -> None:
    for line in notes:
        print(f"warm start: {line}", file=sys.stderr)


def _check_address(address: str) -> None:
    host, sep, port = address.rpartition(":")
    if address not in ("auto",) and not (sep and host and port.isdigit()):
        raise ConfigError(f"--address {address!r}: expected HOST:PORT of a Ray head (or 'auto')")


def _print_summary(name: str, storages: Any, counts: Any, driver: Any) -> None:
    print(
        f"study {name}: {counts.complete} complete, {counts.pruned} pruned, {counts.failed} failed "
        f"({counts.reruns}) in {counts.elapsed_s:.0f} s",
    )
    if driver.recovered:
        print(f"resumed: trials {', '.join(map(str, driver.recovered))} of a stopped driver were failed and retried")
    if counts.best_number is not None:
        from autotune.search.records import read_study

        best = read_study(storages, name).trials[counts.best_number]
        params = ", ".join(f"{k}={_short(v)}" for k, v in best.params.items())
        print(f"best: trial {best.number}: {counts.best_value:.2f} mph ({params})")
    else:
        print("best: no trial completed")
    storage_arg = "" if storages.url.endswith(f"{name}/journal.log") and storages.kind == "journal" else storages.url
    cmd = ["autotune", "dashboard", name] + (["--storage", storage_arg] if storage_arg else [])
    print(f"dashboard: {shlex.join(cmd)}")
    print(f"best net: {shlex.join(['autotune', 'best', name, *cmd[3:], '--export', f'runs/{name}/best'])}")


def _short(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


class _Bar:
    """tqdm on stderr: finished trials of n_trials, pruned / failed / best, elapsed and ETA.

    The ETA is the sooner of the two budgets: the trials left at the rate so far, and the time left
    of ``timeout_s`` (counted from the launch, as the driver counts it).
    """

    def __init__(self, name: str, total: int | None, timeout_s: float | None) -> None:
        import time

        from tqdm import tqdm

        self._t0 = time.monotonic()
        self._timeout = timeout_s
        self._total = total
        fmt = "{desc}: {n_fmt}/{total_fmt} trials |{bar}| [{elapsed}{postfix}]" if total else None
        self.bar = tqdm(total=total, desc=name, unit="trial", file=sys.stderr, dynamic_ncols=True, bar_format=fmt)

    def _eta(self, finished: int) -> str:
        import time

        elapsed = time.monotonic() - self._t0
        left: list[float] = []
        if self._total and finished > 0:
            left.append(elapsed / finished * max(0, self._total - finished))
        if self._timeout is not None:
            left.append(max(0.0, self._timeout - elapsed))
        if not left:
            return "?"
        m, sec = divmod(int(min(left)), 60)
        return f"{m:02d}:{sec:02d}"

    def update(self, c: Any) -> None:
        best = "–" if c.best_value is None else f"{c.best_value:.2f}"
        self.bar.n = max(0, c.finished)
        self.bar.set_postfix_str(
            f"ETA {self._eta(c.finished)}, done {c.complete} pruned {c.pruned} failed {c.failed} "
            f"running {c.running} best {best} mph",
            refresh=False,
        )
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()
