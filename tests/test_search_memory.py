"""A rung's memory: the learner allocates only the replay memory its schedule can fill, and the driver never starts
a rung a worker cannot hold (``[study] max_trial_memory_gb``); a worker Ray kills for memory fails its trial once.

Why: a cold study on seed 1 drew ``experience_size`` 309,884 on 8,167 inputs; its 10k rung allocated 20 GB of replay
memory, Ray's memory monitor killed the worker, and the ``OutOfMemoryError`` ended the whole launch (exit 1).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import optuna
import pytest

from autotune import TrainConfig
from autotune.search import keys, space
from autotune.search.cost import default_memory_cap, rung_memory_bytes
from autotune.search.driver import Driver
from autotune.search.spec import SpecError, parse_spec
from autotune.search.storage import open_storage
from autotune.search.workers import Event
from tests.conftest import FakePool

optuna.logging.set_verbosity(optuna.logging.WARNING)

BASE = TrainConfig(
    ruleset="v2", lanes_side=1, patches_ahead=6, other_agents=1, train_iterations=1200, temporal_window=2,
    experience_size=5000, start_learn_threshold=100, learning_steps_burnin=60, learning_steps_total=600,
    layers="fc:4:relu", batch_size=8,
)  # fmt: skip


def _spec(tmp_path: Path, memory_gb: float | None, **fixed: Any) -> Any:
    data: dict[str, Any] = {
        "study": {"name": "mem", "n_trials": 10, "timeout_s": 600, "race_fraction": 0.0},
        "ladder": {"rungs": [400, 1200]},
        "fixed": {"otherAgents": 1, "temporal_window": 2, "batch_size": 8, "lanes_side": 1, "patches_ahead": 6,
                  "start_learn_threshold": 100, **fixed},
        "space": {"experience_size": {"low": 200, "high": 5000, "log": True},
                  "learning_steps_burnin_fraction": {"low": 0.01, "high": 0.2, "log": True}},
    }  # fmt: skip
    if memory_gb is not None:
        data["study"]["max_trial_memory_gb"] = memory_gb
    return parse_spec(data, source="mem.toml").with_overrides(storage=str(tmp_path / "j.log"))


def _driver(spec: Any) -> Driver:
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    driver.open_study()
    driver.pool = FakePool()
    driver._t0 = time.perf_counter()  # noqa: SLF001
    return driver


def test_the_spec_key_and_its_refusals(tmp_path: Path) -> None:
    spec = _spec(tmp_path, 2.5)
    assert spec.study.max_trial_memory_gb == 2.5
    assert parse_spec(spec.to_dict(), source="mem.toml") == spec
    assert _spec(tmp_path, None).study.max_trial_memory_gb is None
    for bad in (0, -1, "lots"):
        with pytest.raises(SpecError, match=r"mem.toml: \[study\] max_trial_memory_gb"):
            _spec(tmp_path, bad)  # type: ignore[arg-type]
    with pytest.raises(SpecError, match=r"max_trial_memory: unknown key.*max_trial_memory_gb"):
        parse_spec({"study": {"name": "m", "n_trials": 1, "max_trial_memory": 1.0}}, source="m.toml")


def test_a_rungs_memory_and_the_default_cap(tmp_path: Path) -> None:
    """The replay memory counts the rows the rung's schedule can fill, not ``experience_size``; without the key a
    rung may use 60 % of this machine's memory split among the workers."""
    low, high = BASE.replace(train_iterations=400), BASE
    assert low.replay_rows < high.replay_rows <= BASE.experience_size
    assert rung_memory_bytes(high) - rung_memory_bytes(low) == high.replay_bytes - low.replay_bytes > 0
    assert rung_memory_bytes(BASE) == BASE.replay_bytes + 64 * BASE.param_count
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    assert default_memory_cap(4) == int(0.6 * total / 4)
    spec = _spec(tmp_path, None)
    assert _driver(spec)._memory_cap() == default_memory_cap(spec.resources.workers)  # noqa: SLF001
    assert _driver(_spec(tmp_path / "set", 2.5))._memory_cap() == int(2.5e9)  # noqa: SLF001


def test_the_gate_refuses_a_draw_over_the_cap_and_a_trial_climbs_only_as_high_as_memory_allows(
    tmp_path: Path,
) -> None:
    """A draw whose gated rungs need more memory than the cap is unaffordable (redrawn, like one over the cost cap);
    a trial's ladder stops below the first rung over it; a full configuration over it is refused with its cause."""
    low, high = BASE.replace(train_iterations=400), BASE
    between = (rung_memory_bytes(low) + rung_memory_bytes(high)) / 2 / 1e9
    spec = _spec(tmp_path, between)
    driver = _driver(spec)
    params = space.encode(spec, BASE)
    assert driver._held(driver._rung_configs(params)) == driver._rung_configs(params)[:1]  # noqa: SLF001
    assert driver._price(params) is None  # min_top is the last rung: over the cap, refused  # noqa: SLF001
    roomy = _driver(_spec(tmp_path / "r", 1000.0))
    assert roomy._price(params) is not None  # noqa: SLF001

    assert driver._launch_next(0)  # noqa: SLF001 - a sampled trial: the gate redraws until its rungs fit
    task = driver.pool.tasks[0]
    assert task.rungs == (400, 1200) and TrainConfig.from_mapping(task.config).experience_size < 1200
    for budget in task.rungs:
        config = TrainConfig.from_mapping(task.config).replace(train_iterations=budget)
        assert rung_memory_bytes(config) <= between * 1e9

    study = driver.study
    assert study is not None
    study.enqueue_trial(params, user_attrs={keys.CONFIG: BASE.to_mapping()})  # a full configuration over the cap
    assert driver._launch_next(1)  # noqa: SLF001
    refused = study.trials[-1]
    assert refused.state == optuna.trial.TrialState.FAIL and len(driver.pool.tasks) == 1
    assert refused.user_attrs[keys.CAUSE].startswith("refused: its 1,200-iteration rung needs ")
    assert f"over the memory cap of {between:,.1f} GB ([study] max_trial_memory_gb)" in refused.user_attrs[keys.CAUSE]


def test_a_worker_killed_for_memory_fails_its_trial_without_a_retry(tmp_path: Path) -> None:
    """Ray's memory monitor killing a worker is a lost worker whose trial is not retried (the same settings would
    ask for the same memory), where any other lost worker's trial is."""
    driver = _driver(_spec(tmp_path, 1000.0))
    assert driver._launch_next(0) and driver._launch_next(1)  # noqa: SLF001
    driver._handle(Event("lost", 0, cause="out of memory: killed", retry=False))  # noqa: SLF001
    driver._handle(Event("lost", 1, cause="worker lost: died"))  # noqa: SLF001
    driver._enqueue_retries()  # noqa: SLF001
    study = driver.study
    assert study is not None
    oom, lost = study.trials[0], study.trials[1]
    assert oom.state == lost.state == optuna.trial.TrialState.FAIL
    assert oom.user_attrs[keys.CAUSE] == "out of memory: killed" and oom.user_attrs[keys.RETRYABLE] is False
    retries = [t.user_attrs.get(keys.RETRY_OF) for t in study.trials if keys.RETRY_OF in t.user_attrs]
    assert retries == [lost.number]
