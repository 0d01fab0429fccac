"""``autotune status | best | dashboard``: look at a study while it runs or after it ended (read-only).

    autotune status STUDY [--storage URL] [--json]
    autotune best STUDY [--storage URL] [--export DIR] [--json]
    autotune dashboard [STUDY] [--storage URL] [--port N]

``--storage`` is what ``autotune launch`` was given ('' = the embedded runs/<study>/journal.log);
``--artifacts DIR`` where the trained networks were stored when that was not the default.
``dashboard`` serves optuna-dashboard on 127.0.0.1 with the study's artifact store attached (trained
nets and net.js downloadable per trial) until Ctrl-C. Bad input (unknown study — the studies the
storage holds are listed —, unreachable storage): one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import json
import socketserver
import sys
from typing import Any
from wsgiref.simple_server import WSGIRequestHandler, WSGIServer, make_server

from autotune.cliutil import add_storage_arguments, fail

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
    p.add_argument("study", help="study name")
    add_storage_arguments(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run, inspect="status")

    p = subparsers.add_parser(
        "best",
        help="the best trial's settings and score; --export writes its net.json, net.config.json, net.js",
        description="The best trial's score, settings and seed; --export DIR writes its trained network "
        "(net.json + net.config.json) and the site-ready net.js.",
    )
    p.add_argument("study", help="study name")
    add_storage_arguments(p)
    p.add_argument("--export", metavar="DIR", help="write net.json, net.config.json and net.js into DIR")
    p.add_argument("--json", action="store_true", help="print the trial record as one JSON object")
    p.set_defaults(func=run, inspect="best")

    p = subparsers.add_parser(
        "dashboard",
        help="serve optuna-dashboard on 127.0.0.1 for a study's storage (artifacts attached)",
        description="Start optuna-dashboard on 127.0.0.1 for the storage, with the artifact store attached; "
        "serves until Ctrl-C.",
    )
    p.add_argument("study", nargs="?", default="", help="study name (locates the embedded storage and artifacts)")
    add_storage_arguments(p)
    p.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"port on 127.0.0.1 (default {DEFAULT_PORT}; 0: any free port)"
    )
    p.set_defaults(func=run, inspect="dashboard")


def _open(args: argparse.Namespace, study: str) -> Any:
    from autotune.search.storage import open_storage

    return open_storage(args.storage, study, heartbeat=False, artifacts=args.artifacts, create=False)


def _status(args: argparse.Namespace) -> int:
    from autotune.search.records import format_summary, study_summary

    summary = study_summary(_open(args, args.study), args.study)
    if args.json:
        print(json.dumps(summary))
    else:
        print("\n".join(format_summary(summary)))
    return 0


def _best(args: argparse.Namespace) -> int:
    from autotune.search.records import best_trial_record, export_best, race_summary

    storages = _open(args, args.study)
    record = best_trial_record(storages, args.study)
    race = race_summary(storages, args.study)
    paths = export_best(storages, args.study, args.export) if args.export else {}
    if args.json:
        record["exported"] = {name: str(path) for name, path in paths.items()}
        record["race"] = race
        print(json.dumps(record))
        return 0
    print(
        f"best trial {record['number']} of {args.study}: {record['value']:.2f} mph "
        f"({record.get('official_protocol', 'official')}), seed {record.get('seed')}, "
        f"{record.get('param_count', '?')} parameters"
    )
    print("  (the best single net: the leaderboard's number, one seed's draw)")
    if race is not None and race["winner"] is not None:
        w = race["winner"]
        sd = f" ± {w['sd']:.2f}" if w["sd"] is not None else ""
        print(
            f"best configuration by mean over fresh seeds: trial {w['trial']}'s settings: {w['mean']:.2f}{sd} mph "
            f"(n = {w['n']} fresh seeds; {w['selecting_value']:.2f} with the seed that selected it)"
        )
        for row in race["standings"][1:]:
            if row["n"]:
                print(f"  raced: trial {row['trial']}: {row['mean']:.2f} mph over {row['n']} fresh seed(s)")
    elif race is not None:
        print("best configuration by mean over fresh seeds: the seed race has no finished run yet")
    for key, value in record["params"].items():
        print(f"  {key} = {value}")
    config = record.get("config", {})
    if config:
        print("config: " + json.dumps(config))
    for name, path in paths.items():
        print(f"wrote {path}" + (" (paste into the DeepTraffic page)" if name == "net.js" else ""))
    return 0


class _QuietHandler(WSGIRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:  # no access log on the terminal
        pass


class _ThreadingWSGIServer(socketserver.ThreadingMixIn, WSGIServer):
    """wsgiref's server, one thread per request (the dashboard's page fires many API calls at once)."""

    daemon_threads = True


def _dashboard(args: argparse.Namespace) -> int:
    import optuna_dashboard

    from autotune.search.storage import StorageError, load_study

    if not args.storage and not args.study:
        raise StorageError("dashboard: give a STUDY (its embedded storage runs/<study>/) or --storage URL")
    if not 0 <= args.port < 65536:
        raise StorageError(f"--port: {args.port} is not a TCP port (1–65535, or 0 for any free one)")
    storages = _open(args, args.study or "default")
    if args.study:
        load_study(storages, args.study)  # an unknown name fails now, listing the storage's studies
    app = optuna_dashboard.wsgi(storages.storage, artifact_store=storages.artifacts)
    try:
        server = make_server(
            "127.0.0.1", args.port, app, server_class=_ThreadingWSGIServer, handler_class=_QuietHandler
        )
    except OSError as exc:  # e.g. the port is taken
        raise StorageError(
            f"dashboard: cannot listen on 127.0.0.1:{args.port} ({exc.strerror or exc}); try --port"
        ) from None
    url = f"http://127.0.0.1:{server.server_port}/"
    if args.study:
        url += f"dashboard/studies/{storages.storage.get_study_id_from_name(args.study)}"
    print(f"optuna-dashboard for {storages.url} (artifacts {storages.artifact_dir}): {url}  (Ctrl-C to stop)")
    sys.stdout.flush()
    with server:
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass
    return 0


# -- autotune evaluate --trial STUDY:N [--retrain] -------------------------------------------------
def add_trial_arguments(p: argparse.ArgumentParser) -> None:
    """``autotune evaluate``'s options that take the net from a study's trial instead of ``--net``."""
    p.add_argument(
        "--trial",
        metavar="STUDY:N",
        help="a study's COMPLETE trial: evaluate its stored net again (with --retrain: train it again from its "
        "seed) and compare with its stored official score; exit status 1 if they differ",
    )
    add_storage_arguments(
        p,
        storage_help="--trial: the study's storage (default: runs/<study>/journal.log)",
        artifacts_help="--trial: the study's artifact directory (default: beside its storage)",
    )
    p.add_argument("--retrain", action="store_true", help="--trial: retrain its config with its seed, then score it")


def evaluate_trial(args: argparse.Namespace) -> int:
    """``autotune evaluate --trial STUDY:N [--retrain]``: reproduce a trial's official score; 0 if identical, else 1."""
    from autotune.search.records import rescore_trial, retrain_trial, study_resources
    from sim.config import ConfigError

    try:
        if args.trial is None:
            raise ConfigError("--retrain: needs --trial STUDY:N")
        if args.net is not None or args.config is not None:
            raise ConfigError("--trial: takes the net from the study; drop --net/--config")
        study, sep, number = args.trial.rpartition(":")
        if not sep or not study or not number.isdigit():
            raise ConfigError(f"--trial: expected STUDY:N (e.g. quick:12), got '{args.trial}'")
        storages = _open(args, study)
        if args.retrain:
            cpus = int(study_resources(storages, study).get("cpus_per_trial", 1) or 1)
            from autotune import configure_process

            configure_process(threads=max(1, cpus), numba_threads=max(1, cpus))  # as the study's workers ran
            rep = retrain_trial(storages, study, int(number))
        else:
            rep = rescore_trial(storages, study, int(number))
    except ConfigError as exc:  # RecordError included: exit status 1 means "not reproduced" only
        return fail(str(exc))
    if args.json:
        print(json.dumps(rep.to_json()))
    else:
        what = f"retrained from seed {rep.seed}" if rep.how == "retrain" else "its stored net re-scored"
        verdict = "identical" if rep.identical else f"DIFFERENT by {rep.reproduced - rep.stored:+.6g}"
        print(
            f"trial {rep.number} of {rep.study} ({rep.protocol}): stored {rep.stored!r} mph, {what}: "
            f"{rep.reproduced!r} mph — {verdict} ({rep.wall_seconds:.1f} s)"
        )
    return 0 if rep.identical else 1


def run(args: argparse.Namespace) -> int:
    """Run the chosen inspection; 0, 1 when there is no record to show yet, 2 after a one-line error."""
    from autotune.search.records import RecordError
    from sim.config import ConfigError

    try:
        return {"status": _status, "best": _best, "dashboard": _dashboard}[args.inspect](args)
    except RecordError as exc:
        return fail(str(exc), EXIT_NO_RECORD)
    except ConfigError as exc:
        return fail(str(exc))
