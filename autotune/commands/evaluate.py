"""``autotune evaluate``: evaluate a trained convnetjs net (DeepTraffic ``*.json`` + ``*.config.json``) exactly.

(``python -m autotune.evaluate`` is the same command.) The scores are the original's:

    autotune evaluate --net NET.json [--config NET.config.json] [--ruleset v1|v2]
        [--protocol v2-official|v2-heldout|v1-original|v1-distribution|custom] [--seed S] [--other-agents N]
        [--runs R --frames F] [--threads T] [--gauss-cache 0|1] [--no-engine-load] [--json]
    autotune evaluate --trial STUDY:N [--storage URL] [--retrain] [--json]

(``--trial``: a study's trial, its stored net re-scored — or with ``--retrain`` trained again from its
seed — and compared with its stored official score: exit 0 if identical, 1 if not.)

Defaults: config = ``<net>.config.json``; ruleset = the protocol's, else the net's own engine
(v2 iff its config sets ``otherAgents``); protocol = that ruleset's official one (v2-official /
v1-original); other agents (v2) = the net's ``otherAgents``. With ``--json`` the last line is one
JSON object with the fields of ``sim.protocols.EvalResult.to_json()`` (scores per run in run order,
median_site, median, mean, ci95, …) plus ``net`` and ``gauss_cache``. Bad input (missing file, bad
JSON, sizes that do not fit the settings, NaN weights, unknown layer types) prints one line
``error: <field>: <problem>`` and exits with status 2.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from autotune.cliutil import add_storage_arguments
from sim.config import ConfigError


def add_parser(subparsers: Any) -> None:
    """``autotune evaluate``: its options, help text and ``func=run``."""
    p = subparsers.add_parser(
        "evaluate",
        help="evaluate a trained convnetjs net exactly as the original",
        description="Evaluate a trained convnetjs DeepTraffic net in the exact simulator (original JS scores).",
    )
    p.add_argument("--net", help="convnetjs Net JSON (the argument of value_net.fromJSON); or --trial STUDY:N")
    p.add_argument("--config", help="DeepTraffic settings JSON (default: <net>.config.json beside the net)")
    p.add_argument("--ruleset", choices=("v1", "v2"), help="engine (default: the protocol's, else the net's own)")
    p.add_argument(
        "--protocol",
        default="official",
        help="v2-official, v2-heldout (the official harness on other runs), v1-original, v1-distribution, custom "
        "(default: the ruleset's official)",
    )
    p.add_argument(
        "--seed",
        type=int,
        help="protocol seed (default: the protocol's: 1, 10⁶, 2000, 1000, 0; v2-heldout's moves its runs: run k "
        "uses Park–Miller seed seed + k + 1)",
    )
    p.add_argument(
        "--other-agents", type=int, help="v2: extra agents driven by the net (default: the net's otherAgents)"
    )
    p.add_argument("--runs", type=int, help="override the protocol's number of runs")
    p.add_argument("--frames", type=int, help="override the protocol's frames per run")
    p.add_argument("--threads", type=int, help="numba threads (custom protocol)")
    p.add_argument(
        "--gauss-cache",
        type=int,
        choices=(0, 1),
        default=0,
        help="convnetjs Gaussian cache flag before the brain build (0 = fresh process)",
    )
    p.add_argument(
        "--no-engine-load",
        action="store_true",
        help="v1-original: no engine-construction draws after the brain build (the learner_scores.json "
        "harness; evaluate.js has them)",
    )
    p.add_argument("--json", action="store_true", help="print the result as one JSON object on the last line")
    add_trial_arguments(p)
    p.set_defaults(func=run)


def evaluate(args: argparse.Namespace) -> dict[str, Any]:
    """The evaluation of the parsed arguments, as the JSON-able result."""
    from autotune.convnet.netjson import load
    from autotune.learner.brain_policy import evaluate_net
    from sim.protocols import OFFICIAL, PROTOCOLS, V1_DISTRIBUTION, V1_ORIGINAL

    # the protocol names, with "_" for "-", and these spellings (None: the ruleset's official protocol)
    aliases = {"official": None, "evaluate.js": V1_ORIGINAL, "v1-dist": V1_DISTRIBUTION}
    net, settings = load(args.net, args.config)
    key = args.protocol.strip().lower().replace("_", "-")
    if key not in PROTOCOLS and key not in aliases:
        raise ConfigError(f"protocol: '{args.protocol}' is not a protocol; use one of {', '.join(PROTOCOLS)}")
    protocol = key if key in PROTOCOLS else aliases[key]
    if protocol is None:
        protocol = OFFICIAL[args.ruleset or settings.engine]
    result = evaluate_net(
        net,
        settings,
        protocol,
        ruleset=args.ruleset,
        seed=args.seed,
        other_agents=args.other_agents,
        runs=args.runs,
        frames=args.frames,
        threads=args.threads,
        gauss_cache=args.gauss_cache,
        engine_load=not args.no_engine_load,
    )
    out = result.to_json()
    out["net"] = str(args.net)
    out["hidden_layers"] = net.hidden
    out["engine_version"] = settings.engine
    out["gauss_cache"] = args.gauss_cache
    return out


def run(args: argparse.Namespace) -> int:
    """Evaluate and print; 0 (``--trial``: 0 if the score is reproduced, else 1); bad input raises ConfigError."""
    if args.trial is not None or args.retrain:
        return evaluate_trial(args)
    if args.net is None:
        raise ConfigError("--net: required (or --trial STUDY:N)")
    out = evaluate(args)
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"{out['net']}: {out['hidden_layers'] or 'linear'} ({out['engine_version']} net) — {out['protocol']} "
            f"on {out['ruleset']}, {out['runs']} runs × {out['frames']} frames, {out['other_agents']} other agents"
        )
        print(
            f"site median {out['median_site']:.2f} mph | median {out['median']:.3f} | mean {out['mean']:.3f} "
            f"(95% CI {out['ci95'][0]:.3f}–{out['ci95'][1]:.3f}) | min {out['min']:.2f} max {out['max']:.2f}"
        )
        print(f"{out['wall_seconds']:.1f} s, {out['frames_per_second']:,.0f} frames/s")
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
    from autotune.search.storage import open_storage

    if args.trial is None:
        raise ConfigError("--retrain: needs --trial STUDY:N")
    if args.net is not None or args.config is not None:
        raise ConfigError("--trial: takes the net from the study; drop --net/--config")
    study, sep, number = args.trial.rpartition(":")
    if not sep or not study or not number.isdigit():
        raise ConfigError(f"--trial: expected STUDY:N (e.g. quick:12), got '{args.trial}'")
    # a missing trial or artifact is a ConfigError too (exit 2): exit status 1 means "not reproduced" only
    storages = open_storage(args.storage, study, heartbeat=False, artifacts=args.artifacts, read_only=True)
    if args.retrain:
        cpus = int(study_resources(storages, study).get("cpus_per_trial", 1) or 1)
        from autotune import configure_process

        configure_process(threads=max(1, cpus), numba_threads=max(1, cpus))  # as the study's workers ran
        rep = retrain_trial(storages, study, int(number))
    else:
        rep = rescore_trial(storages, study, int(number))
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
