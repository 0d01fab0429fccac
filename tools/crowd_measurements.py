"""Regenerate the measured-crowd package data that ``autotune compare`` reads (dashboards/data/crowd/*.json).

    python tools/crowd_measurements.py own-nets            # own_nets.json: 25 human nets, own weights (~3 min)
    python tools/crowd_measurements.py spread              # spread.json: 3 nets × 50 protocol seeds (~15 min)
    python tools/crowd_measurements.py replay --workers N  # replay.json: 20 v2 + 15 v1 configurations × 2 seeds
                                                           # (hours of CPU; resumable from --work)

Each file records the command that made it. Scoring is exact and deterministic (own-nets, spread:
the same numbers on any machine); the replay trains with our learner from fixed seeds. ``--out``
writes elsewhere (default: the package's file). Bad arguments: one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dashboards import crowd_data, measured, spread  # noqa: E402
from sim.config import ConfigError  # noqa: E402


def _own_nets(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else crowd_data.data_dir() / measured.OWN_NETS_FILE

    def show(s: measured.OwnNetScore) -> None:
        print(f"{s.crowd_id}: {s.score:.2f} mph ({s.engine}, {s.protocol}; claimed {s.claimed:.2f}; {s.seconds:.1f} s)")

    scores = measured.score_own_nets(args.ids or None, progress=show)
    path = measured.write_document(measured.own_nets_document(scores), out)
    print(f"wrote {path} ({len(scores)} nets)")
    return 0


def _spread(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else crowd_data.data_dir() / spread.SPREAD_FILE
    t0 = time.perf_counter()
    data = spread.crowd_spread(args.nets or spread.DEFAULT_NETS, args.seeds, cache=Path(args.cache), progress=print)
    path = measured.write_document(spread.spread_document(data), out)
    print(f"wrote {path} ({len(data.nets)} nets × {args.seeds} seeds, {time.perf_counter() - t0:.0f} s)")
    for net in data.nets:
        s = spread.spread_stats(net, data.threshold)
        print(
            f"  {net.name} ({net.engine}, {net.protocol}): site number {min(s.full):.2f}–{max(s.full):.2f} mph, "
            f"sd {s.sd[-1]:.3f} over {len(net.seeds)} seeds; sd < {data.threshold:g} from n = {s.runs_needed}"
        )
    return 0


def _replay(args: argparse.Namespace) -> int:
    from dashboards import crowd_replay

    out = Path(args.out) if args.out else crowd_data.data_dir() / measured.REPLAY_FILE
    groups = measured.replay_selection(args.v2, args.v1)
    if args.ids:
        wanted = set(args.ids)
        unknown = wanted - {g[0].id for g in groups}
        if unknown:
            raise ConfigError(f"--ids: {', '.join(sorted(unknown))} not among the selected configurations")
        groups = [g for g in groups if g[0].id in wanted]
    command = " ".join(["python tools/crowd_measurements.py", *sys.argv[1:]])
    t0 = time.perf_counter()
    print(f"replaying {len(groups)} configuration(s) × {args.seeds} seed(s) on {args.workers} worker(s)")

    def show(task: crowd_replay.ReplayTask, run: measured.ReplayRun, cached: bool) -> None:
        score = f"{run.score:.2f} mph" if run.score is not None else f"{run.state}: {run.cause}"
        print(f"  {task.crowd_id} seed {task.seed_index}: {score} ({'cached' if cached else f'{run.seconds:.0f} s'})")

    table = crowd_replay.run_replay(
        groups, args.seeds, work_dir=Path(args.work), workers=args.workers, max_iterations=args.max_iterations,
        command=command, progress=show,
    )  # fmt: skip
    path = measured.write_document(measured.replay_document(table), out)
    print(f"wrote {path} ({len(table.entries)} configurations, {time.perf_counter() - t0:.0f} s)")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True, metavar="{own-nets,spread,replay}")
    own = sub.add_parser("own-nets", help="score the human nets with their own weights (own_nets.json)")
    own.add_argument("--ids", nargs="*", help="only these nets (default: all 25)")
    own.add_argument("--out", default="", help="file to write (default: the package's own_nets.json)")
    own.set_defaults(func=_own_nets)
    spr = sub.add_parser("spread", help="the official protocol of a few nets under many seeds (spread.json)")
    spr.add_argument("--nets", nargs="*", help=f"crowd net ids (default: {' '.join(spread.DEFAULT_NETS)})")
    spr.add_argument("--seeds", type=int, default=spread.DEFAULT_SEEDS, help="protocol seeds per net (default 50)")
    spr.add_argument("--cache", default=str(spread.SPREAD_CACHE), help="per-seed results (default runs/.spread-cache)")
    spr.add_argument("--out", default="", help="file to write (default: the package's spread.json)")
    spr.set_defaults(func=_spread)
    rep = sub.add_parser("replay", help="retrain the best-claimed crowd configurations (replay.json)")
    rep.add_argument("--v2", type=int, default=measured.REPLAY_V2, help="best-claimed v2 configurations (20)")
    rep.add_argument("--v1", type=int, default=measured.REPLAY_V1, help="best-claimed v1 configurations (15)")
    rep.add_argument("--ids", nargs="*", help="only these configurations (crowd ids) of the selection")
    rep.add_argument("--seeds", type=int, default=measured.REPLAY_SEEDS, help="training seeds each (default 2)")
    rep.add_argument("--workers", type=int, default=1, help="training processes (default 1)")
    rep.add_argument("--max-iterations", type=int, default=None, help="cap training (rehearsals only; recorded)")
    rep.add_argument("--work", default="runs/crowd-replay-table", help="per-seed results, for resuming")
    rep.add_argument("--out", default="", help="file to write (default: the package's replay.json)")
    rep.set_defaults(func=_replay)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (ConfigError, crowd_data.CrowdDataError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
