"""``autotune replay``: draw one evaluation run of a trained net as a GIF, an MP4 or an HTML page (issue 9 §4).

    autotune replay STUDY [--trial N] [--storage URL] [--artifacts DIR] --out run.gif|run.mp4|run.html
    autotune replay --net NET.json [--config NET.config.json] --out run.html
        [--frames 600] [--every 2] [--seed 0] [--run-frames 2000] [--ruleset v1|v2] [--fps 15]

A study's trial (default: its best COMPLETE trial) is taken from its ``artifact_net_json``
artifact and its stored config (``autotune.search.records.export_trial``). The run is the
``custom`` protocol's world ``--seed``; ``--frames``/``--every`` choose the frames drawn (the run
goes on to ``--run-frames`` for its score): ``dashboards.replay.record_run`` records it and
``dashboards.replay_render.write_replay`` draws it. The study is read read-only. Bad input (``--out``
where it cannot be written — checked first —, a storage that is not there, damaged or not Optuna's):
one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

from autotune.cliutil import add_storage_arguments, output_file
from sim.config import ConfigError


def add_parser(subparsers: Any) -> None:
    """``autotune replay``: its options, help text and ``func=run``."""
    p = subparsers.add_parser(
        "replay",
        help="draw one evaluation run of a trained net (road, occupancy grid, safety view, input slice)",
        description="Record one evaluation run of a study's trial (or any --net) frame by frame in the exact engine "
        "and draw the paper's four views as an animated GIF, an MP4 or a self-contained HTML page.",
    )
    p.add_argument("study", nargs="?", help="study name (its best COMPLETE trial unless --trial)")
    p.add_argument("--trial", type=int, help="trial number within the study (default: the best trial)")
    add_storage_arguments(
        p,
        storage_help="the study's storage (default: runs/<study>/journal.log)",
        artifacts_help="the study's artifact directory (default: beside its storage)",
    )
    p.add_argument("--net", help="a convnetjs net JSON instead of a study trial")
    p.add_argument("--config", help="--net: its DeepTraffic settings (default: <net>.config.json beside it)")
    p.add_argument("--out", required=True, help="output file: *.gif, *.mp4 or *.html")
    p.add_argument("--frames", type=int, default=600, help="frames drawn from the start of the run (default 600)")
    p.add_argument("--every", type=int, default=2, help="draw every K-th frame (default 2)")
    p.add_argument("--seed", type=int, default=0, help="custom-protocol seed of the run (default 0)")
    p.add_argument("--run-frames", type=int, help="frames in the whole run, for its score (default 2000)")
    p.add_argument("--ruleset", choices=("v1", "v2"), help="engine (default: the net's own)")
    p.add_argument("--fps", type=float, default=15.0, help="GIF/MP4 frames per second (default 15)")
    p.set_defaults(func=run)


def _load(args: argparse.Namespace) -> tuple[str, Any, Any]:
    """(name, net, settings) from ``--net`` or from the study's trial."""
    from autotune.convnet.netjson import load

    if args.net is not None:
        if args.study is not None or args.trial is not None:
            raise ConfigError("--net: replaces the study's trial; drop STUDY/--trial")
        path = Path(args.net)
        if not path.is_file():
            raise ConfigError(f"--net: no such file: {path}")
        net, settings = load(path, args.config)
        return path.stem, net, settings
    if args.study is None:
        raise ConfigError("replay: give a STUDY (its best trial, or --trial N) or --net FILE")
    if args.config is not None:
        raise ConfigError("--config: only with --net (a trial's settings come from the study)")
    from autotune.search.records import export_best, export_trial
    from autotune.search.storage import open_storage

    storages = open_storage(args.storage, args.study, heartbeat=False, artifacts=args.artifacts, read_only=True)
    with tempfile.TemporaryDirectory(prefix="replay-") as tmp:
        if args.trial is None:
            paths = export_best(storages, args.study, tmp)
        else:
            paths = export_trial(storages, args.study, args.trial, tmp)
        net, settings = load(paths["net.json"], paths["net.config.json"])
    which = "best" if args.trial is None else f"trial {args.trial}"
    return f"{args.study} {which}", net, settings


def run(args: argparse.Namespace) -> int:
    """Record the run and write ``--out``; 0; bad input raises ConfigError."""
    from dashboards.replay import record_run
    from dashboards.replay_render import FORMATS, write_replay

    out = Path(args.out)
    if out.suffix.lower() not in FORMATS:
        raise ConfigError(f"--out: '{out}' has no replay format; use a name ending in {', '.join(FORMATS)}")
    output_file(out, "--out")  # before the run is recorded
    name, net, settings = _load(args)
    rec = record_run(
        net,
        settings,
        name=name,
        ruleset=args.ruleset,
        seed=args.seed,
        frames=args.frames,
        every=args.every,
        run_frames=args.run_frames,
    )
    path = write_replay(rec, out, fps=args.fps)
    print(
        f"{path}: {len(rec)} frames of {name} ({rec.config.ruleset}, seed {rec.seed}); "
        f"run score {rec.score:.2f} mph over {rec.run_frames} frames"
    )
    return 0
