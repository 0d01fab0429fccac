"""Trials the sampler did not propose: finished ones added as they are, and full configurations to train.

* ``add_finished`` writes finished trials given as plain records (``records.TrialRecord``) into a
  study — how the crowd's self-reported submissions become a study optuna-dashboard and the
  reports read like any other;
* ``enqueue_configs`` enqueues full training configurations (``ConfigTrial``: the params shown
  in the dashboard, the ``TrainConfig`` mapping the driver trains, the seed, provenance), and
  ``run_enqueued`` trains them with the driver on Ray workers under ``replay_spec`` — the paper's
  space widened to hold every enqueued value, no pruning, the whole training — as ``autotune crowd
  replay`` does with the crowd's settings. Each trial is scored with the official protocol of its
  own config's ruleset.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from autotune.search import keys
from autotune.search.driver import Driver, Progress, StudyCounts
from autotune.search.records import StudyRecord, TrialRecord, snapshot, to_optuna_distribution
from autotune.search.spec import StudySpec
from autotune.search.storage import StorageError, Storages

__all__ = [
    "REPLAY_TRIAL_TIMEOUT_S", "ConfigTrial", "add_finished", "enqueue_configs", "replay_spec", "run_enqueued",
]  # fmt: skip

REPLAY_TRIAL_TIMEOUT_S = 24 * 3600.0  # a crowd setting trains as long as it says (up to 1,000,000 iterations)


def _maximizing(storage: optuna.storages.BaseStorage, study_name: str) -> optuna.Study:
    study = optuna.create_study(study_name=study_name, storage=storage, direction="maximize", load_if_exists=True)
    if study.direction != optuna.study.StudyDirection.MAXIMIZE:
        raise StorageError(f"study '{study_name}' exists and minimizes; scores are maximized: use another --study")
    return study


def _describe(study: optuna.Study, study_attrs: Mapping[str, Any], metric_name: str | None) -> None:
    """Set the study's user attrs and say what its value is (optuna-dashboard shows the metric name)."""
    for key, value in study_attrs.items():
        study.set_user_attr(key, value)
    if metric_name is not None:
        with warnings.catch_warnings():  # Optuna calls set_metric_names experimental
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            study.set_metric_names([metric_name])


def add_finished(
    storages: Storages | None,
    study_name: str,
    trials: Sequence[TrialRecord],
    study_attrs: Mapping[str, Any],
    *,
    metric_name: str | None = None,
) -> StudyRecord:
    """Add ``trials`` (finished, with their values, params, distributions and times) to ``study_name``.

    The study is created if absent (direction maximize; ``storages`` None: in memory), the trials
    take the next numbers in the order given, and ``study_attrs`` (and ``metric_name``: what the
    values are) are set on the study. Returns the study as it stands afterwards.
    """
    storage = optuna.storages.InMemoryStorage() if storages is None else storages.storage
    study = _maximizing(storage, study_name)
    study.add_trials(
        [
            FrozenTrial(
                number=0,
                state=TrialState[t.state],
                value=t.value,
                datetime_start=t.datetime_start,
                datetime_complete=t.datetime_complete,
                params=dict(t.params),
                distributions={k: to_optuna_distribution(d) for k, d in t.distributions.items()},
                user_attrs=dict(t.user_attrs),
                system_attrs={},
                intermediate_values={},
                trial_id=0,
            )
            for t in trials
        ]
    )
    _describe(study, study_attrs, metric_name)
    return snapshot(study)


@dataclasses.dataclass(frozen=True)
class ConfigTrial:
    """A full training configuration to enqueue as a trial."""

    params: Mapping[str, Any]
    """Its settings as the study's parameters (sampling coordinates), for the dashboard and the sampler."""
    config: Mapping[str, Any]
    """``TrainConfig.to_mapping()``: what the driver trains — settings no parameter carries included."""
    seed: int
    """The training seed."""
    user_attrs: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    """More of the record (provenance, e.g. ``keys.CROWD_ID``, ``keys.SEED_INDEX``)."""


def enqueue_configs(
    storages: Storages,
    study_name: str,
    trials: Iterable[ConfigTrial],
    study_attrs: Mapping[str, Any],
    *,
    metric_name: str | None = None,
) -> int:
    """Enqueue ``trials`` in ``study_name`` (created if absent, maximize), set ``study_attrs`` and ``metric_name``.

    Returns how many were enqueued.

    Every one is enqueued, also when the same params are already there (the seed or config may
    differ); the caller leaves out what it has enqueued before.
    """
    verbosity = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)  # no INFO line for a new study (restored below)
    try:
        study = _maximizing(storages.storage, study_name)
    finally:
        optuna.logging.set_verbosity(verbosity)
    _describe(study, study_attrs, metric_name)
    added = 0
    for t in trials:
        attrs = {**t.user_attrs, keys.CONFIG: dict(t.config), keys.SEED: int(t.seed)}
        study.enqueue_trial(dict(t.params), user_attrs=attrs, skip_if_exists=False)
        added += 1
    return added


def replay_spec(
    name: str,
    *,
    storage: str,
    workers: int,
    n_trials: int,
    params: Iterable[Mapping[str, Any]] = (),
    activations: Sequence[str] = (),
) -> StudySpec:
    """The spec enqueued configurations run under: the paper's space (``space.DEFAULT_SPACE``), no pruning.

    Random sampler (only a v1 trial's unused ``other_agents`` is ever drawn), no pruning (a replay
    trains to the end), a one-day trial limit, ``report_points`` 5 for the learning curve. The space
    is widened to hold every enqueued value in ``params`` (the crowd went beyond the paper's bounds:
    50 lanes, 1-neuron layers, linear and svm outputs), so Optuna stores them without complaint;
    the activation choices get every one of ``activations`` — pass the same in every run of a study
    (a categorical's choices may not change within a study).
    """
    from autotune.search.space import DEFAULT_SPACE
    from autotune.search.spec import parse_spec

    spec = parse_spec(
        {
            "study": {
                "name": name, "sampler": "random", "pruner": "none", "n_trials": n_trials, "seed": 0,
                "storage": storage, "trial_timeout_s": REPLAY_TRIAL_TIMEOUT_S,
            },
            "space": DEFAULT_SPACE,
            "evaluation": {"report_points": 5, "quick_runs": 10, "quick_frames": 2000, "n_warmup_steps": 0},
            "resources": {"workers": workers},
        },
        source="crowd replay",
    )  # fmt: skip
    seen: dict[str, list[Any]] = {}
    for p in params:
        for key, value in p.items():
            seen.setdefault(key.rsplit("_", 1)[0] if key.startswith(("neurons_", "activation_")) else key, []).append(
                value
            )
    dims = []
    for d in spec.space:
        if d.kind == "categorical":
            d = dataclasses.replace(d, choices=(*d.choices, *(c for c in activations if c not in d.choices)))
        elif seen.get(d.name):
            assert d.low is not None and d.high is not None
            low, high = min(d.low, *seen[d.name]), max(d.high, *seen[d.name])
            if d.log and low <= 0:  # cannot widen a log scale to 0: Optuna stores the value with a warning
                low = d.low
            d = dataclasses.replace(d, low=low, high=high)
        dims.append(d)
    return dataclasses.replace(spec, space=tuple(dims))


def run_enqueued(storages: Storages, spec: StudySpec, progress: Progress | None = None) -> StudyCounts:
    """Train the study's waiting trials with the driver on ``spec.resources.workers`` Ray workers.

    ``spec`` is ``replay_spec``'s, with ``n_trials`` the number of enqueued (non-retry) trials, so the
    budget is exactly them; nothing waiting starts no Ray at all. Returns the driver's final
    ``StudyCounts``; Ctrl-C propagates after the running trials were failed (retryable).
    """
    return Driver(spec, storages, progress=progress).run()
