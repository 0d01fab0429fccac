"""``autotune train`` (or ``python -m autotune.train``): train one DeepTraffic configuration and export the result.

    autotune train --config study_configs/train_network_basic_v2.toml --seed 1 --out runs/nb_v2_s1
    autotune train --preset strong --set trainIterations=20000 --seed 3 --out runs/strong_s3

Writes into ``--out``:

* ``config.json`` — the resolved training config (flat) and the net.js-style settings;
* ``curve.csv`` / ``curve.json`` — the learning curve (frames, quick score, mean reward, loss, …);
* ``result.json`` — counters (frames, decisions, updates, wall/CPU time, it/s), training-run scores,
  divergence/stop status and the final **official score**: v2-official (500 × 2,000, lexicographic
  median) for v2, v1-original (evaluate.js: 10 × 100,000) for v1 — evaluated exactly as the
  original harness would (``autotune.learner.official``: float64 forward pass, the trained weights
  after the JSON text round trip that turns NaN into 0, the original's ``Math.random`` seeding);
* ``checkpoint.pt`` — ``torch.save`` of the state dict, the config mapping, the seed and the curve;
* ``net.json`` + ``net.config.json`` — convnetjs Net JSON (``value_net.toJSON()`` format) and its
  settings; ``net.js`` — a net.js for the DeepTraffic page with the weights appended.

Bad input (unknown key, out-of-range value, unreadable file) prints one line naming the field and
exits with status 2.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from autotune.learner.config import PRESETS, ConfigError, TrainConfig, load_toml, preset
from autotune.learner.official import evaluate_official, official_protocol


def _parse_value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def load_config(args: argparse.Namespace) -> TrainConfig:
    if (args.config is None) == (args.preset is None):
        raise ConfigError("config: give exactly one of --config FILE.toml and --preset NAME")
    config = load_toml(args.config) if args.config else preset(args.preset)
    if args.set:
        changes: dict[str, Any] = {}
        for item in args.set:
            if "=" not in item:
                raise ConfigError(f"--set {item}: expected KEY=VALUE (e.g. --set gamma=0.9)")
            key, value = item.split("=", 1)
            changes[key.strip()] = _parse_value(value.strip())
        config = config.replace(**changes)
    return config


def write_curve(out: Path, result: Any) -> None:
    fields = ["frames", "quick_score", "mean_reward", "loss", "decisions", "epsilon", "wall_seconds"]
    rows = [p._asdict() for p in result.curve]
    with (out / "curve.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        for row in rows:
            w.writerow({k: ("" if v is None else v) for k, v in row.items()})
    (out / "curve.json").write_text(json.dumps(_jsonable(rows), indent=1) + "\n")


def _jsonable(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x


def add_parser(subparsers: Any) -> None:
    """``autotune train``: its options, help text and ``func=run``."""
    parser = subparsers.add_parser(
        "train", help="train one DeepTraffic configuration and export the result", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--config", help="training config (TOML; flat or [opt]/[tdtrainer_options] form)")
    parser.add_argument("--preset", help=f"a named reference config instead of --config ({', '.join(PRESETS)})")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one setting (repeatable)")
    parser.add_argument("--seed", type=int, default=0, help="trial seed (all randomness derives from it)")
    parser.add_argument(
        "--stream",
        choices=["independent", "original"],
        default="independent",
        help="randomness: independent generators from --seed (default), or the original harness's "
        "Math.random := mulberry32(seed) stream for every learner draw — with --set dtype=float64 "
        "the original's own training run",
    )
    parser.add_argument("--out", required=True, help="output directory (created)")
    parser.add_argument("--report-points", type=int, default=10, help="learning-curve points (default 10)")
    parser.add_argument("--no-quick-eval", action="store_true", help="no quick scores on the learning curve")
    parser.add_argument("--no-eval", action="store_true", help="skip the final official evaluation")
    parser.add_argument("--eval-seed", type=int, default=None, help="Math.random seed of the official evaluation")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Train, write the outputs into ``--out``; 0; bad input raises ConfigError."""
    config = load_config(args)
    if args.report_points < 1:
        raise ConfigError(f"--report-points: must be ≥ 1, got {args.report_points}")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(str(exc)) from None  # as before: the OS's own message, e.g. [Errno 20] Not a directory

    import torch

    from autotune.convnet.netjson import export_netjs, write_net
    from autotune.learner.training import train

    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(total=config.total_frames, unit="frame", unit_scale=True, desc=f"train seed {args.seed}")

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.update(done - bar.n)

    (out / "config.json").write_text(
        json.dumps(
            {
                "config": config.to_mapping(),
                "settings": config.to_deepqlearn(),
                "seed": args.seed,
                "stream": args.stream,
            },
            indent=1,
        )
        + "\n"
    )
    t0 = time.perf_counter()
    result = train(
        config,
        args.seed,
        report_points=args.report_points,
        quick_eval=not args.no_quick_eval,
        progress=progress,
        stream=args.stream,
    )
    if bar is not None:
        bar.close()
    status = "diverged: " + str(result.diverged_reason) if result.diverged else "ok"
    print(
        f"trained {result.decisions:,} decisions / {result.frames:,} frames in {result.train_seconds:.1f} s "
        f"({result.iterations_per_second:,.0f} it/s); {status}",
        file=sys.stderr,
    )
    write_curve(out, result)
    convnet = result.convnet()
    settings = config.settings
    write_net(out / "net.json", convnet, settings)
    (out / "net.js").write_text(export_netjs(convnet, settings))
    torch.save(
        {
            "state_dict": result.module.state_dict(),
            "config": config.to_mapping(),
            "seed": args.seed,
            "hidden_layers": config.hidden,
            "curve": [p._asdict() for p in result.curve],
        },
        out / "checkpoint.pt",
    )
    summary: dict[str, Any] = {"config": config.to_mapping(), **result.summary()}
    if not args.no_eval:
        protocol = official_protocol(config)
        ev = evaluate_official(convnet, config, seed=args.eval_seed)
        summary["official"] = {
            "protocol": protocol,
            "seed": ev.seed,
            "median_site": ev.median_site,
            "mean": ev.mean,
            "std": ev.std,
            "scores": ev.scores,
            "wall_seconds": ev.wall_seconds,
        }
        print(f"{protocol}: {ev.median_site:.2f} mph (mean {ev.mean:.2f}, {ev.wall_seconds:.1f} s)", file=sys.stderr)
    summary["total_wall_seconds"] = time.perf_counter() - t0
    (out / "result.json").write_text(json.dumps(_jsonable(summary), indent=1) + "\n")
    return 0
