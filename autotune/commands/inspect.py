"""``autotune status | best | dashboard``: look at a study while it runs or after it ended (read-only).

    autotune status STUDY [--storage URL] [--json]
    autotune best STUDY [--storage URL] [--export DIR] [--json]
    autotune dashboard [STUDY] [--storage URL] [--port N]

``--storage`` is what ``autotune launch`` was given ('' = the embedded runs/<study>/journal.log);
STUDY may also be a study's run directory (``runs/paper``, a benchmark's ``runs/search_quality/…/cold-s0``):
its journal.log and artifacts are read, the name taken from its study.toml;
``--artifacts DIR`` where the trained networks were stored when that was not the default.
``dashboard`` serves optuna-dashboard on 127.0.0.1 with the study's artifact store attached (trained
nets and net.js downloadable per trial) until Ctrl-C, read-only (the page cannot create, change or
delete studies). All three open the storage read-only: they create no journal, database, table,
study or artifact directory. Bad input (unknown study — the studies the storage holds are listed —,
unreachable, damaged or foreign storage, an ``--export`` directory that cannot be written — checked
first): one line on stderr, exit status 2; a study with nothing to show yet (no complete trial): one
line, exit status 1.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from autotune.cliutil import add_storage_arguments, fail, output_dir

EXIT_NO_RECORD = 1  # the study exists but has nothing to show yet
DEFAULT_PORT = 8080

COMMANDS = ("status", "best", "dashboard")


def add_parser(subparsers: Any) -> None:
    """``autotune status``, ``autotune best`` and ``autotune dashboard``: options, help and ``func=run``."""
    p = subparsers.add_parser(
        "status",
        help="a study's trial counts by state, best trial and throughput",
        description="Counts by trial state, the best trial, and throughput (trials/h, frames/s) of a study.",
    )
    p.add_argument("study", help="study name, or its run directory (runs/<study>)")
    add_storage_arguments(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run, inspect="status", process_settings=False)

    p = subparsers.add_parser(
        "best",
        help="the best trial and the best single net; --export writes that net's net.json, net.config.json, net.js",
        description="The best trial's score, settings and seed, the best single net (a trial's value or a kept "
        "ladder rung, whichever scored higher) and the seed race's best configuration; --export DIR writes the "
        "best single net (net.json + net.config.json with its own settings) and the site-ready net.js.",
    )
    p.add_argument("study", help="study name, or its run directory (runs/<study>)")
    add_storage_arguments(p)
    p.add_argument("--export", metavar="DIR", help="write net.json, net.config.json and net.js into DIR")
    p.add_argument("--json", action="store_true", help="print the trial record as one JSON object")
    p.set_defaults(func=run, inspect="best", process_settings=False)

    p = subparsers.add_parser(
        "dashboard",
        help="serve optuna-dashboard on 127.0.0.1 for a study's storage (artifacts attached)",
        description="Start optuna-dashboard on 127.0.0.1 for the storage, with the artifact store attached; "
        "serves until Ctrl-C.",
    )
    p.add_argument(
        "study",
        nargs="?",
        default="",
        help="study name (locates the embedded storage and artifacts) or its run directory",
    )
    add_storage_arguments(p)
    p.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"port on 127.0.0.1 (default {DEFAULT_PORT}; 0: any free port)"
    )
    p.set_defaults(func=run, inspect="dashboard", process_settings=False)


def _open(args: argparse.Namespace, study: str) -> Any:
    from autotune.search.storage import open_storage

    return open_storage(args.storage, study, heartbeat=False, artifacts=args.artifacts, read_only=True)


def _status(args: argparse.Namespace) -> int:
    from autotune.search.records import format_summary, study_summary

    summary = study_summary(_open(args, args.study), args.study)
    if args.json:
        print(json.dumps(summary))
    else:
        print("\n".join(format_summary(summary)))
    return 0


def _net_name(step: dict[str, Any]) -> str:
    """``trial 12's 90,000-iteration rung (74.95)`` or ``trial 41 (75.10)``: one net of a refinement lineage."""
    where = f"trial {step['trial']}" + (f"'s {step['budget']:,}-iteration rung" if step["budget"] is not None else "")
    return f"{where} ({step['score']:.2f})" if isinstance(step.get("score"), (int, float)) else where


def _best(args: argparse.Namespace) -> int:
    from autotune.search.records import best_net, best_trial_record, export_best_net, race_summary, read_study

    if args.export:
        output_dir(args.export, "--export")  # before anything is read
    storages = _open(args, args.study)
    record = best_trial_record(storages, args.study)
    race = race_summary(storages, args.study)
    net = best_net(read_study(storages, args.study))
    paths = export_best_net(storages, args.study, args.export) if args.export else {}
    if args.json:
        record["exported"] = {name: str(path) for name, path in paths.items()}
        record["race"] = race
        if net is not None and (net["budget"] is not None or net["lineage"]):  # a kept rung, or a refined net
            record["best_net"] = net
        print(json.dumps(record))
        return 0
    print(
        f"best trial {record['number']} of {args.study}: {record['value']:.2f} mph "
        f"({record.get('official_protocol', 'official')}), seed {record.get('seed')}, "
        f"{record.get('param_count', '?')} parameters"
    )
    if net is not None and net["budget"] is not None:
        print(
            f"best single net: trial {net['trial']}'s {net['budget']:,}-iteration rung ({net['state'].lower()} "
            f"trial, seed {net['seed']}), {net['score']:.2f} mph: a complete training at that budget, scored "
            f"officially{_epsilon(net)}"
        )
        print("  (the leaderboard's number, one seed's draw; --export writes this net)")
    else:
        print("  (the best single net: the leaderboard's number, one seed's draw)")
    if net is not None and net["lineage"]:
        steps = " ← ".join(_net_name(step) for step in net["lineage"])
        print(f"  refined: trial {net['trial']} trained on from {steps} (the fresh training it started from last)")
    if race is not None and race.get("provisional"):
        w = race["winner"]
        sd = f" ± {w['sd']:.2f}" if w["sd"] is not None else ""
        print(
            f"best configuration over fresh seeds so far (before the seed race): trial {w['trial']}'s "
            f"settings{_at(w)}: {w['mean']:.2f}{sd} mph (n = {w['n']} fresh seeds{_selected(w)})"
        )
        print("  (ranked by the mean of each configuration's fresh seeds, once it has 3; the race decides later)")
        for row in race["standings"][1:4]:
            print(f"  also: trial {row['trial']}{_at(row)}: {row['mean']:.2f} mph over {row['n']} fresh seeds")
    elif race is not None and race["winner"] is not None:
        w = race["winner"]
        sd = f" ± {w['sd']:.2f}" if w["sd"] is not None else ""
        print(
            f"best configuration over fresh seeds (the seed race): trial {w['trial']}'s settings{_at(w)}: "
            f"{w['mean']:.2f}{sd} mph (n = {w['n']} fresh seeds{_selected(w)})"
        )
        if w["ranked_on"] and w["ranked_on"] < w["n"]:
            print(
                f"  (won on the {w['ranked_on']} fresh seed(s) every finalist finished: {w['paired_mean']:.2f} mph; "
                "a run the deadline stopped counts for no finalist)"
            )
        if w["finalist"]:
            print("  (ranked by paired per-seed comparisons, Wilcoxon's signed ranks: one collapsed seed is one lost "
                  "seed)")  # fmt: skip
        else:
            print("  (the pick after the race's tail: the halving's winner's mean over all its fresh seeds fell below "
                  "this one's, a rival of its last round)")  # fmt: skip
        for row in race["standings"][1:]:
            if row["n"]:
                paired = (
                    f"; {row['paired_mean']:.2f} on the seeds the finalists share"
                    if row["finalist"] and row["paired_mean"] is not None and row["ranked_on"] < row["n"]
                    else ""
                )
                print(
                    f"  raced: trial {row['trial']}{_at(row)}: {row['mean']:.2f} mph over {row['n']} fresh seed(s)"
                    f"{paired}{' (finalist)' if row['finalist'] else ''}"
                )
    elif race is not None:
        print("best configuration over fresh seeds (the seed race): no finished run yet")
    for key, value in record["params"].items():
        print(f"  {key} = {value}")
    config = record.get("config", {})
    if config:
        print("config: " + json.dumps(config))
    for name, path in paths.items():
        print(f"wrote {path}" + (" (paste into the DeepTraffic page)" if name == "net.js" else ""))
    return 0


def _selected(row: dict[str, Any]) -> str:
    """'; S with the seed that selected it' for a standing with a selecting score, else ''."""
    value = row.get("selecting_value")
    return f"; {value:.2f} with the seed that selected it" if value is not None else ""


def _epsilon(net: dict[str, Any]) -> str:
    """' at ε_test E' for a net scored at a known ε_test, else ''."""
    e = net.get("epsilon_test_time")
    return f" at ε_test {e:g}" if isinstance(e, (int, float)) else ""


def _at(standing: dict[str, Any]) -> str:
    """' at B iterations' for an entrant raced at a kept rung's budget, else ''."""
    return "" if standing.get("budget") is None else f" at {standing['budget']:,} iterations"


def _dashboard(args: argparse.Namespace) -> int:
    from autotune.search.dashboard import DashboardServer
    from autotune.search.storage import StorageError

    if not args.storage and not args.study:
        raise StorageError("dashboard: give a STUDY (its embedded storage runs/<study>/) or --storage URL")
    if not 0 <= args.port < 65536:
        raise StorageError(f"--port: {args.port} is not a TCP port (1–65535, or 0 for any free one)")
    storages = _open(args, args.study or "default")
    server = DashboardServer(storages, args.study, args.port)
    print(
        f"optuna-dashboard for {storages.url} (artifacts {storages.artifact_dir}; read-only): {server.url}  "
        "(Ctrl-C to stop)"
    )
    sys.stdout.flush()
    server.serve_forever()
    return 0


def _run_directory(args: argparse.Namespace) -> None:
    """A STUDY with a '/' (and no --storage) is a run directory: read its journal.log, under the name its
    study.toml gives (the directory's own name when it has none). Paths are what a user copies from ``ls runs/``;
    a bare name stays a study name (runs/<study>/)."""
    from pathlib import Path

    from autotune.search.storage import StorageError

    if args.storage or "/" not in args.study:  # a bare name is a study name (runs/<study>/)
        return
    path = Path(args.study)
    if not (path / "journal.log").is_file():
        raise StorageError(
            f"study '{args.study}': no journal.log in that directory; give a study name (runs/<study>/), a run "
            "directory that holds journal.log, or --storage"
        )
    name = path.resolve().name
    toml = path / "study.toml"
    if toml.is_file():
        import tomllib

        try:
            name = str(tomllib.loads(toml.read_text())["study"]["name"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise StorageError(
                f"{toml}: no [study] name to read ({exc}); pass the name and --storage {path}/journal.log"
            ) from exc
    args.storage, args.study = str(path / "journal.log"), name


def run(args: argparse.Namespace) -> int:
    """Run the chosen inspection; 0, or 1 when there is no record to show yet (bad input raises ConfigError)."""
    from autotune.search.records import RecordError

    _run_directory(args)
    try:
        return {"status": _status, "best": _best, "dashboard": _dashboard}[args.inspect](args)
    except RecordError as exc:  # not bad input: the study has nothing to show yet (its own exit status)
        return fail(str(exc), EXIT_NO_RECORD)
