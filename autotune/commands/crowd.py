"""``autotune crowd import | replay``: the crowd beside the automated search.

    autotune crowd import [--storage URL] [--study crowd] [--own-nets]
    autotune crowd replay [--filter EXPR] [--limit N] [--seeds K] [--workers N] [--storage URL] [--study crowd-replay]
                          [--enqueue-only]

``import`` writes the packaged crowd (``dashboards.crowd_data``) as an Optuna study, one COMPLETE
trial per scored submission (idempotent, ``dashboards.crowd.import_crowd``), with the shipped
own-weight scores of the 25 human nets (``dashboards.measured``); ``--own-nets`` scores them again
first (exact evaluator, own engine and official protocol: the same numbers) and stores those.
``replay`` enqueues the selected crowd settings, K seeds each, as trials of the replay study
(``dashboards.crowd_replay``: params under the search's names, the submission's full config in the
``config`` user attr, a seed fixed by (crowd id, seed index)) and runs them with the search driver on
``--workers`` Ray workers: the whole training (the submission's own trainIterations, never fewer) and
the official protocol of the submission's engine, no pruning. Then it prints self-reported against
replayed (mean over seeds). Rerunning enqueues only missing (setting, seed) pairs and runs only
waiting trials. ``--filter`` is a small expression over the CSV
columns, e.g. ``engine_version == 'v2' and reported_score_mph > 70`` (``dashboards.crowd_filter``:
parsed with ``ast``, never ``eval``). Bad input: one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from autotune.cliutil import add_storage_arguments
from sim.config import ConfigError

EXIT_INTERRUPTED = 130


def add_parser(subparsers: Any) -> None:
    """``autotune crowd`` (import, replay): options, help and ``func=run``."""
    p = subparsers.add_parser(
        "crowd",
        help="the human crowd's submissions as an Optuna study (import) or re-run by our learner (replay)",
        description="import: write the crowd sample's 116 scored submissions (of 164) as an Optuna study whose values "
        "are the authors' claims; replay: enqueue crowd "
        "settings as trials of a study that the search driver trains and scores with the exact engine.",
    )
    actions = p.add_subparsers(dest="crowd_action", metavar="<action>", required=True)
    imp = actions.add_parser("import", help="write the crowd as an Optuna study (one trial per scored submission)")
    add_storage_arguments(imp, artifacts_help=None)
    imp.add_argument("--study", default="crowd", help="study name (default: crowd)")
    imp.add_argument(
        "--own-nets",
        action="store_true",
        help="score the 25 human nets with their own weights now (exact engine; default: the shipped scores)",
    )
    imp.set_defaults(func=run, command_name="crowd-import", process_settings=False)
    rep = actions.add_parser(
        "replay", help="retrain and score crowd settings (K seeds each) with our learner and the exact engine"
    )
    rep.add_argument("--filter", default="", help="expression over CSV columns, e.g. \"engine_version == 'v2'\"")
    rep.add_argument("--limit", type=int, default=0, help="replay at most N submissions (0: all selected)")
    rep.add_argument("--seeds", type=int, default=1, help="training seeds per setting (default 1)")
    rep.add_argument("--workers", type=int, default=1, help="Ray workers = trials trained in parallel (default 1)")
    add_storage_arguments(rep, artifacts_help=None)
    rep.add_argument("--study", default="crowd-replay", help="study name (default: crowd-replay)")
    rep.add_argument(
        "--enqueue-only", action="store_true", help="only enqueue; a later replay of the same study runs them"
    )
    rep.set_defaults(func=run, command_name="crowd-replay")


def _import(args: argparse.Namespace) -> int:
    from autotune.search.storage import open_storage
    from dashboards.crowd import import_crowd, score_own_nets

    storages = open_storage(args.storage, args.study)
    own = score_own_nets(lambda line: print(line, file=sys.stderr)) if args.own_nets else None
    _study, result = import_crowd(storages, args.study, own_net_scores=own)
    unscored = sum(1 for r in result.skipped.values() if r == "no reported score")
    print(
        f"{storages.url}: study '{result.study_name}': {result.added} trial(s) added, {result.existing} already "
        f"there; skipped {len(result.skipped)} submission(s) ({unscored} without a reported score, "
        f"{len(result.skipped) - unscored} with settings our learner refuses)"
    )
    for sid, reason in result.skipped.items():
        if reason != "no reported score":
            print(f"  skipped {sid}: {reason}")
    if own:
        print(f"own-net scores stored for {len(own)} net(s)")
    return 0


def _replay(args: argparse.Namespace) -> int:
    from autotune.search.records import read_study
    from autotune.search.storage import open_storage
    from dashboards import crowd_data, crowd_filter, crowd_replay

    if args.seeds < 1 or args.limit < 0 or args.workers < 1:
        raise ConfigError("--seeds and --workers must be ≥ 1 and --limit ≥ 0")
    subs = crowd_filter.select(crowd_data.load_submissions(), args.filter, args.limit)
    storages = open_storage(args.storage, args.study)
    added, existing, skipped = crowd_replay.enqueue_replay(storages, args.study, subs, args.seeds)
    print(
        f"{storages.url}: study '{args.study}': {len(subs)} crowd setting(s) selected; {added} trial(s) enqueued, "
        f"{existing} already there; {len(skipped)} skipped"
    )
    for sid, reason in skipped.items():
        print(f"  skipped {reason}" if reason.startswith(sid) else f"  skipped {sid}: {reason}")
    if args.enqueue_only:
        print(f"the enqueued trials wait in the study; 'autotune crowd replay --study {args.study}' runs them")
        return 0
    study = read_study(storages, args.study)
    if not study.trials:
        print("nothing to run: the study has no trial")
        return 0
    waiting = len(study.with_states("WAITING"))
    if waiting:
        print(f"training {waiting} trial(s) on {args.workers} worker(s): full training, official protocol")
    try:  # starts no Ray when nothing waits (a rerun)
        counts = crowd_replay.run_replay_study(
            storages, study, storage=args.storage, workers=args.workers, progress=_ReplayProgress(waiting)
        )
    except KeyboardInterrupt:
        print("interrupted: running trials failed (retryable); rerun the same command to go on", file=sys.stderr)
        return EXIT_INTERRUPTED
    finished_before = len(study.with_states("COMPLETE", "PRUNED", "FAIL"))
    ran = counts.complete + counts.pruned + counts.failed - finished_before
    if ran:
        print(
            f"ran {ran} trial(s) in {counts.elapsed_s:.0f} s; study: {counts.complete} complete, {counts.pruned} "
            f"pruned, {counts.failed} failed ({counts.reruns})"
        )
    else:
        print("nothing to run: every trial of the study has run already")
    rows = crowd_replay.replay_table(read_study(storages, args.study), subs)
    if rows:
        print(crowd_replay.format_replay_table(rows))
    return 0


class _ReplayProgress:
    """One stderr line whenever a replay trial finishes."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.base: int | None = None
        self.seen = 0
        self.t0 = time.perf_counter()

    def __call__(self, c: Any) -> None:
        finished = c.complete + c.pruned + c.failed
        if self.base is None:
            self.base = finished
        done = finished - self.base
        if done != self.seen:
            self.seen = done
            print(
                f"  replay: {done} finished of {self.total} ({c.complete} complete, {c.failed} failed), "
                f"{c.running} running, {time.perf_counter() - self.t0:.0f} s",
                file=sys.stderr,
            )


def run(args: argparse.Namespace) -> int:
    """Run the chosen action; 0 (130 on Ctrl-C); bad input raises ConfigError."""
    return {"crowd-import": _import, "crowd-replay": _replay}[args.command_name](args)
