"""What a study costs beyond its trials: scheduling, storage and transfer overhead, and worker utilisation.

    python bench/search_overhead.py                                   # smoke.toml, 10 trials of 10,000 iterations
    python bench/search_overhead.py --config study_configs/quick.toml --n-trials 20
    python bench/search_overhead.py --set trainIterations=30000 --workers 2 --n-trials 8

Runs the study in this process (``autotune.search.driver.Driver``: local Ray, embedded journal in
a temporary directory) and reads the timeline back from the storage. Per trial the driver's view
(Optuna's start at ``ask`` → complete at ``tell``) is compared with the worker's own busy time
(``trial_wall_seconds``, ``trial_cpu_seconds`` inside ``run_trial``). Over the trial phase (first
``ask`` → last ``tell``; Ray start and worker warm-up are reported apart):

* overhead = worker time in neither a trial nor the final idle tail / (workers × phase wall):
  asking the sampler, storage writes (reports, user attrs, artifacts), Ray round trips for every
  intermediate score and the trial's transfer — target ≤ 5 %;
* utilisation = Σ in-trial CPU seconds / (workers × phase wall) — target ≥ 90 %; on a machine that
  other jobs share, CPU seconds < wall seconds and this falls with the load, not the service;
* tail = the workers' idle time after their last trial while others finish (a finite study's end);
* trials/hour over the whole run and over the trial phase.

Prints a table and one JSON line (prefix ``JSON``). The conditions (CPUs, load average) are printed.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default=str(ROOT / "study_configs" / "smoke.toml"), help="study spec (TOML)")
    parser.add_argument("--n-trials", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a [fixed] setting (default trainIterations=10000)",
    )
    args = parser.parse_args(argv)

    from autotune.search.driver import Driver
    from autotune.search.spec import parse_spec
    from autotune.search.storage import open_storage

    data = tomllib.loads(Path(args.config).read_text())
    fixed = data.setdefault("fixed", {})
    sets = args.set or ["trainIterations=10000"]
    for item in sets:
        key, _, value = item.partition("=")
        fixed[key.strip()] = _value(value.strip())
    data["study"]["name"] = "overhead"
    data["study"].pop("timeout_s", None)
    data["study"]["n_trials"] = args.n_trials
    data.setdefault("resources", {})["workers"] = args.workers
    spec = parse_spec(data, source=args.config)

    with tempfile.TemporaryDirectory() as tmp:
        storages = open_storage(str(Path(tmp) / "journal.log"), "overhead")
        driver = Driver(spec, storages, state_dir=Path(tmp))
        driver.open_study()
        t0 = time.perf_counter()
        counts = driver.run()
        wall = time.perf_counter() - t0
        assert driver.study is not None
        trials = [t for t in driver.study.trials if t.state.is_finished() and "trial_wall_seconds" in t.user_attrs]
    if not trials:
        print("no trial finished", file=sys.stderr)
        return 1

    start = {t.number: t.datetime_start.timestamp() for t in trials}  # type: ignore[union-attr]
    end = {t.number: t.datetime_complete.timestamp() for t in trials}  # type: ignore[union-attr]
    phase0, phase1 = min(start.values()), max(end.values())
    phase = phase1 - phase0
    workers = spec.resources.workers
    in_trial = sum(t.user_attrs["trial_wall_seconds"] for t in trials)
    cpu = sum(t.user_attrs["trial_cpu_seconds"] for t in trials)
    by_worker: dict[str, float] = {}
    for t in trials:
        by_worker[t.user_attrs["worker"]] = max(by_worker.get(t.user_attrs["worker"], 0.0), end[t.number])
    tail = sum(phase1 - last for last in by_worker.values()) + (workers - len(by_worker)) * phase
    overhead = workers * phase - in_trial - tail
    driver_view = sum(end[t.number] - start[t.number] for t in trials)
    load1, load5, _ = os.getloadavg()
    result = {
        "config": args.config,
        "fixed_overrides": sets,
        "trials": len(trials),
        "complete": counts.complete,
        "pruned": counts.pruned,
        "failed": counts.failed,
        "workers": workers,
        "wall_seconds": wall,
        "startup_seconds": driver.startup_seconds,
        "phase_seconds": phase,
        "in_trial_wall_seconds": in_trial,
        "in_trial_cpu_seconds": cpu,
        "per_trial_overhead_seconds": (driver_view - in_trial) / len(trials),
        "overhead_pct": 100 * overhead / (workers * phase),
        "tail_idle_pct": 100 * tail / (workers * phase),
        "utilisation_pct": 100 * cpu / (workers * phase),
        "busy_pct": 100 * in_trial / (workers * phase),
        "trials_per_hour": 3600 * len(trials) / wall,
        "trials_per_hour_phase": 3600 * len(trials) / phase,
        "cpus": os.cpu_count(),
        "loadavg_1_5": [load1, load5],
    }
    rows = [
        (
            "trials (complete / pruned / failed)",
            f"{len(trials)} ({counts.complete} / {counts.pruned} / {counts.failed})",
        ),
        ("workers", f"{workers}"),
        ("wall time", f"{wall:.1f} s (Ray start + warm-up {driver.startup_seconds:.1f} s, trials {phase:.1f} s)"),
        ("in-trial wall / CPU seconds", f"{in_trial:.1f} s / {cpu:.1f} s"),
        ("per-trial driver-side overhead", f"{result['per_trial_overhead_seconds'] * 1000:.0f} ms"),
        ("scheduling/storage/transfer overhead", f"{result['overhead_pct']:.2f} % of workers × wall (target ≤ 5 %)"),
        ("idle tail (study end)", f"{result['tail_idle_pct']:.1f} %"),
        ("worker utilisation (CPU)", f"{result['utilisation_pct']:.1f} % (target ≥ 90 %)"),
        ("workers busy (wall)", f"{result['busy_pct']:.1f} %"),
        ("trials/hour", f"{result['trials_per_hour']:.0f} (trial phase: {result['trials_per_hour_phase']:.0f})"),
        ("conditions", f"{os.cpu_count()} CPUs, load average {load1:.2f} / {load5:.2f} (1 / 5 min)"),
    ]
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")
    print("JSON " + json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
