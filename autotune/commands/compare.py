"""``autotune compare``: an automated study beside the crowd, as one HTML report and figures in optuna-dashboard.

    autotune compare STUDY [--crowd STUDY] [--replay STUDY] [--storage URL] --out report.html [--no-dashboard]
                     [--spread-runs N | --no-spread]

Writes the self-contained HTML report (``dashboards.report``) and attaches its figures to the study
in optuna-dashboard; its measured-crowd panels read the package data (``dashboards.measured``,
``dashboards.spread``: own-weight scores, the replay table, the site's number under 50 protocol
seeds, up to ``--spread-runs`` runs per evaluation), so it scores nothing itself. The studies are
read read-only; the only write is the figures and note attached to the existing STUDY (none with
``--no-dashboard``). Bad input (``--out`` where it cannot be written — checked first —, a storage
or study that is not there, damaged or not Optuna's): one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from autotune.search.records import StudyRecord
    from autotune.search.storage import Storages

from autotune.cliutil import add_storage_arguments, output_file
from sim.config import ConfigError


def add_parser(subparsers: Any) -> None:
    """``autotune compare``: options, help and ``func=run``."""
    cmp = subparsers.add_parser(
        "compare",
        help="HTML report: an automated study beside the crowd (the paper's figures and four insights)",
        description="Write one self-contained HTML report comparing STUDY with the crowd, and attach its figures "
        "and a note to STUDY for optuna-dashboard.",
    )
    cmp.add_argument("study", help="the automated study")
    cmp.add_argument("--crowd", default="", help="crowd study (default: 'crowd' in the storage, else the package data)")
    cmp.add_argument("--replay", default="", help="crowd replay study (default: 'crowd-replay' if the storage has it)")
    add_storage_arguments(cmp, artifacts_help=None)
    cmp.add_argument("--out", required=True, help="HTML file to write")
    cmp.add_argument("--seed", type=int, default=0, help="seed of the t-SNE and importance evaluators (default 0)")
    cmp.add_argument("--no-dashboard", action="store_true", help="do not attach the figures to the study")
    cmp.add_argument(
        "--spread-runs", type=int, default=500, metavar="N",
        help="spread panel: runs per evaluation shown up to N (default 500, the site's; shipped data)",
    )  # fmt: skip
    cmp.add_argument("--no-spread", action="store_true", help="leave out the evaluation-spread panel")
    cmp.set_defaults(func=run, command_name="compare", process_settings=False)


def run(args: argparse.Namespace) -> int:
    """Write the report (and attach it); 0; bad input raises ConfigError."""
    from autotune.search.records import read_study
    from autotune.search.storage import open_storage
    from dashboards import crowd, report
    from dashboards.extract import Empty
    from dashboards.spread import load_spread_runs

    out = output_file(args.out, "--out")
    if not args.no_spread and args.spread_runs < 2:
        raise ConfigError(f"--spread-runs: need at least 2 runs, got {args.spread_runs}")

    storages = open_storage(args.storage, args.study, read_only=True)
    automated = read_study(storages, args.study)
    # one storage holds all three studies when --storage names it (a journal is read once: at 5,000 trials
    # each read replays ~100 MB); the embedded default keeps each study in its own runs/<study>/ journal
    shared = storages if args.storage.strip() else None
    if args.crowd:
        crowd_study = read_study(shared or open_storage(args.storage, args.crowd, read_only=True), args.crowd)
    else:
        crowd_study = _other_study(shared, args.storage, crowd.CROWD_STUDY) or crowd.crowd_study(None)
    replay: StudyRecord | None
    if args.replay:
        replay = read_study(shared or open_storage(args.storage, args.replay, read_only=True), args.replay)
    else:
        replay = _other_study(shared, args.storage, crowd.REPLAY_STUDY)
    spread = Empty("not drawn (--no-spread)") if args.no_spread else load_spread_runs(args.spread_runs)
    built = report.build_report(automated, crowd_study, replay=replay, spread=spread, seed=args.seed)
    path = report.write_html(built, out)
    shown = sum(1 for s in built.sections if not isinstance(s.figure, report.Empty))
    print(f"wrote {path} ({shown} of {len(built.sections)} panels with data)")
    for s in built.sections:
        if isinstance(s.figure, report.Empty):
            print(f"  {s.title}: {s.figure.reason}")
    if not args.no_dashboard:
        writable = open_storage(args.storage, args.study, heartbeat=False, create=False)  # the study exists
        ids = report.attach_to_dashboard(writable, args.study, built)
        print(f"attached {len(ids)} figure(s) and a note to study '{args.study}' for optuna-dashboard")
    return 0


def _other_study(shared: Storages | None, storage: str, name: str) -> StudyRecord | None:
    """The study ``name`` if present: in the already opened ``shared`` storage, else found by ``storage``."""
    from autotune.search.records import find_study, read_study_if_present

    return read_study_if_present(shared, name) if shared is not None else find_study(storage, name)
