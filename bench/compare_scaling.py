"""How ``autotune compare`` scales with the study's size: wall time of the whole command at N trials.

    python bench/compare_scaling.py                       # N = 250, 1000, 5000
    python bench/compare_scaling.py --trials 1000 --profile   # where the time goes (cProfile, top 30)
    python bench/compare_scaling.py --like runs/paper/journal.log  # copies of a launched study's trials

A day of search makes thousands of trials, so the report must stay interactive at that size. For each
N a synthetic study is written to a journal in a temporary folder: N trials drawn at random from
``paper.toml``'s space (``space.sample`` with a seeded RandomSampler, ``space.to_config`` at the top
rung), each with the user attrs the driver stores (``config``, ``param_count``, ``frames_simulated``,
``rungs``, ``seed``) and a value from a fixed function of its settings plus noise; a tenth PRUNED (no
value), as in a study. Then ``autotune compare STUDY --storage JOURNAL --out report.html``
runs as a subprocess (as users run it: the figures attached to the study; ``--no-dashboard`` leaves that
out), timed as a whole process (import, read, statistics, figures, HTML), with the
report's shipped-data panels as in any run. Prints a table (N, seconds, seconds per 1,000 trials, HTML
size) and one JSON line (prefix ``JSON``), with the machine's load average before each run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def write_study(path: Path, name: str, n: int, seed: int = 0) -> None:
    """A synthetic ``paper.toml`` study of ``n`` finished trials in the journal ``path``."""
    import numpy as np
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    from autotune.search import keys, space
    from autotune.search.gate import distributions
    from autotune.search.spec import load_spec
    from sim.config import ConfigError

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    spec = load_spec(ROOT / "study_configs" / "paper.toml")
    dists = distributions(spec)
    top = spec.ladder[-1]
    storage = JournalStorage(JournalFileBackend(str(path)))
    study = optuna.create_study(study_name=name, storage=storage, direction="maximize")
    study.set_user_attr(keys.STUDY_SPEC, spec.to_dict())
    draws = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=seed))
    rng = np.random.default_rng(seed)
    trials: list[optuna.trial.FrozenTrial] = []
    while len(trials) < n:
        params = space.sample(draws.ask(), spec)
        try:
            config = space.to_config(spec, params, budget=top)
        except ConfigError:  # a draw deepqlearn rejects is no trial
            continue
        score = 62.0 + 6.0 * math.exp(-config.epsilon_test_time * 4) - 2.0 * abs(math.log10(config.learning_rate) + 3)
        score += float(rng.normal(0.0, 2.0))
        pruned = rng.random() < 0.1
        attrs = {
            keys.SOURCE: keys.SOURCE_AUTOTUNE,
            keys.CONFIG: config.to_mapping(),
            keys.SEED: int(rng.integers(2**31)),
            keys.PARAM_COUNT: int(config.param_count),
            keys.FRAMES_SIMULATED: int(config.train_iterations * 15 + 1_000_000),
            keys.RUNGS: [{keys.BUDGET: b, keys.SCORE: score - 3.0 + i, keys.SECONDS: 5.0 * (i + 1)}
                         for i, b in enumerate(spec.ladder)],
        }  # fmt: skip
        trials.append(optuna.trial.create_trial(
            params=params, distributions=dists, user_attrs=attrs,
            state=optuna.trial.TrialState.PRUNED if pruned else optuna.trial.TrialState.COMPLETE,
            value=None if pruned else score, intermediate_values={1: score - 3.0},
        ))  # fmt: skip
    study.add_trials(trials)


def clone_study(path: Path, name: str, n: int, source: Path) -> None:
    """A study of ``n`` trials in the journal ``path`` made of a real study's finished trials, round robin.

    Synthetic trials carry a few attrs; a launched study's carry the training curve, the deepqlearn
    settings, every rung and the artifact ids (~10–20 kB each), which is what reading a journal costs.
    Each copy keeps all of that; its learning rate moves by a relative 1e-6 per round so that every
    copy is its own configuration (the insights count configurations once).
    """
    import copy

    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    from autotune.search import keys
    from autotune.search.storage import open_storage, study_names

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storages = open_storage(str(source), "_", read_only=True)
    names = study_names(storages)
    if not names:
        raise SystemExit(f"--like {source}: the journal holds no study")
    real = optuna.load_study(study_name=names[0], storage=storages.storage)
    finished = [t for t in real.get_trials(deepcopy=False) if t.state.is_finished()]
    if not finished:
        raise SystemExit(f"--like {source}: study '{names[0]}' has no finished trial")
    study = optuna.create_study(study_name=name, storage=JournalStorage(JournalFileBackend(str(path))),
                                direction="maximize")  # fmt: skip
    for key, value in real.user_attrs.items():
        study.set_user_attr(key, value)
    block = len(real.get_trials(deepcopy=False))
    trials = []
    for i in range(n):
        t, k = finished[i % len(finished)], i // len(finished)
        attrs = copy.deepcopy(t.user_attrs)
        params = dict(t.params)
        if isinstance(attrs.get(keys.CONFIG), dict):
            attrs[keys.CONFIG]["learning_rate"] *= 1 + 1e-6 * k
        if "learning_rate" in params:
            params["learning_rate"] *= 1 + 1e-6 * k
        if keys.RACE_OF in attrs:
            attrs[keys.RACE_OF] = int(attrs[keys.RACE_OF]) + k * block
        trials.append(optuna.trial.create_trial(
            params=params, distributions=t.distributions, user_attrs=attrs, system_attrs=t.system_attrs,
            state=t.state, value=t.value if t.state == optuna.trial.TrialState.COMPLETE else None,
            intermediate_values=t.intermediate_values,
        ))  # fmt: skip
    study.add_trials(trials)


_RUN = "import sys; from autotune.cli import main; sys.exit(main(sys.argv[1:]))"
_PROFILE = (
    "import cProfile, pstats, sys; from autotune.cli import main; prof = cProfile.Profile(); "
    "rc = prof.runcall(main, sys.argv[1:]); pstats.Stats(prof).sort_stats('cumulative').print_stats(30); sys.exit(rc)"
)


def time_compare(journal: Path, name: str, out: Path, profile: bool, dashboard: bool) -> float:
    """Wall seconds of one ``autotune compare`` process (under cProfile with ``profile``, its top printed)."""
    cmd = [sys.executable, "-c", _PROFILE if profile else _RUN]
    cmd += ["compare", name, "--storage", str(journal), "--out", str(out)]
    cmd += [] if dashboard else ["--no-dashboard"]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)  # noqa: S603
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"compare failed (exit {res.returncode}): {res.stderr.strip()[-2000:]}")
    if profile:
        print(res.stdout[-12000:])
    return wall


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", default="250,1000,5000", help="study sizes N, comma-separated")
    ap.add_argument("--profile", action="store_true", help="run compare under cProfile and print the top entries")
    ap.add_argument("--no-dashboard", action="store_true", help="pass --no-dashboard (time the report alone)")
    ap.add_argument(
        "--like", metavar="JOURNAL", default=None,
        help="copy a launched study's finished trials (all their attrs) instead of synthetic ones",
    )  # fmt: skip
    args = ap.parse_args(argv)
    try:
        sizes = [int(s) for s in args.trials.split(",") if s.strip()]
    except ValueError:
        ap.error(f"--trials: comma-separated whole numbers of trials, e.g. 250,1000,5000; got {args.trials!r}")
    if not sizes or min(sizes) < 1:
        ap.error(f"--trials: at least one study size, each ≥ 1; got {args.trials!r}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            journal = Path(tmp) / f"study{n}.log"
            name = f"synthetic{n}"
            t0 = time.perf_counter()
            if args.like:
                clone_study(journal, name, n, Path(args.like))
            else:
                write_study(journal, name, n)
            made = time.perf_counter() - t0
            load = os.getloadavg()[0]
            out = Path(tmp) / f"report{n}.html"
            wall = time_compare(journal, name, out, args.profile, not args.no_dashboard)
            rows.append({"trials": n, "seconds": wall, "per_1000_s": wall / n * 1000, "html_bytes": out.stat().st_size,
                         "load_before": load, "write_study_s": made})  # fmt: skip
            print(f"N={n:>6,}  compare {wall:7.1f} s  ({wall / n * 1000:6.1f} s per 1,000)  html "
                  f"{out.stat().st_size / 1e6:5.1f} MB  load {load:.2f}", flush=True)  # fmt: skip
    print("JSON " + json.dumps({"bench": "compare_scaling", "cpus": os.cpu_count(), "like": args.like, "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
