"""[study] denoise: the sampler sees each finished trial at a forest's estimate; the storage keeps its own."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import optuna
import pytest
from optuna.distributions import BaseDistribution, CategoricalDistribution, FloatDistribution, IntDistribution
from optuna.trial import TrialState, create_trial

from autotune.search import space
from autotune.search.balance import BalancedSampler
from autotune.search.denoise import DenoisedSampler, encode, leaf_quantile
from autotune.search.driver import denoise_reference_step, make_sampler
from autotune.search.gate import CostGatedSampler
from autotune.search.spec import SpecError, StudySpec, load_spec, parse_spec

optuna.logging.set_verbosity(optuna.logging.ERROR)

DISTS: dict[str, BaseDistribution] = {"x": FloatDistribution(0.0, 10.0), "noise": FloatDistribution(0.0, 1.0)}


def _spec(**study: Any) -> StudySpec:
    return parse_spec({
        "study": {"name": "den", "n_trials": 10, "timeout_s": 60, "sampler_startup_trials": 6, **study},
        "ladder": {"rungs": [400, 1200, 3600], "min_top": 1200},
        "fixed": {"otherAgents": 1, "temporal_window": 0, "experience_size": 500, "batch_size": 8},
        "space": {
            "lanes_side": {"low": 0, "high": 2}, "patches_ahead": {"low": 1, "high": 4},
            "learning_rate": {"low": 1e-6, "high": 1e-2, "log": True},
            "method": {"choices": ["sgd", "adagrad", "adadelta"]},
            "n_layers": {"low": 0, "high": 2}, "neurons": {"low": 2, "high": 8},
            "activation": {"choices": ["relu", "tanh"]},
        },
    })  # fmt: skip


def _study(n: int, seed: int = 0, lucky: float | None = None) -> optuna.Study:
    """Trials whose true score is 60 + x at step 1 (+1 at step 3), measured with sd-2 noise; PRUNED at step 1 when
    x < 5, else COMPLETE at step 3. ``lucky``: one more trial at x = 1 that scored that much."""
    rng = np.random.default_rng(seed)
    study = optuna.create_study(direction="maximize")
    for _ in range(n):
        x, z = float(rng.uniform(0, 10)), float(rng.uniform(0, 1))
        first = 60 + x + rng.normal(0, 2)
        if x < 5:
            study.add_trial(create_trial(state=TrialState.PRUNED, params={"x": x, "noise": z}, distributions=DISTS,
                                         intermediate_values={1: first}))  # fmt: skip
        else:
            top = 61 + x + rng.normal(0, 2)
            study.add_trial(create_trial(value=top, params={"x": x, "noise": z}, distributions=DISTS,
                                         intermediate_values={1: first, 3: top}))  # fmt: skip
    if lucky is not None:
        study.add_trial(create_trial(state=TrialState.PRUNED, params={"x": 1.0, "noise": 0.5}, distributions=DISTS,
                                     intermediate_values={1: lucky}))  # fmt: skip
    return study


def test_encode_uses_the_samplers_coordinates() -> None:
    d = {"a": FloatDistribution(1e-4, 1.0, log=True), "b": IntDistribution(0, 9),
         "c": CategoricalDistribution(["relu", "tanh"])}  # fmt: skip
    row = encode({"a": 1e-2, "b": 4, "c": "tanh"}, d, ["a", "b", "c", "d"])
    assert row[:3] == pytest.approx([math.log(1e-2), 4.0, 1.0])
    assert row[3] < -1e8  # a parameter the trial lacks: one value no space reaches


def test_a_short_history_is_shown_as_it_is() -> None:
    study = _study(5)
    shown = DenoisedSampler(optuna.samplers.RandomSampler(), 3, 0, min_rungs=24).shown(study)
    assert [(t.state, t.value) for t in shown] == [(t.state, t.value) for t in study.trials]


def test_rungs_without_a_finite_score_do_not_count_towards_the_fit() -> None:
    study = optuna.create_study(direction="maximize")
    for i in range(30):
        study.add_trial(create_trial(state=TrialState.PRUNED, params={"x": float(i % 10), "noise": 0.5},
                                     distributions=DISTS, intermediate_values={1: float("nan")}))  # fmt: skip
    shown = DenoisedSampler(optuna.samplers.RandomSampler(), 3, 0).shown(study)
    assert all(t.state == TrialState.PRUNED and t.value is None for t in shown)


def test_finished_trials_are_shown_complete_at_the_models_value_and_the_storage_keeps_its_own() -> None:
    study = _study(80, lucky=80.0)
    running = study.ask()
    shown = {t.number: t for t in DenoisedSampler(optuna.samplers.RandomSampler(), 3, 0).shown(study)}
    lucky = study.trials[80]
    assert lucky.state == TrialState.PRUNED and lucky.value is None  # the storage is untouched
    assert shown[80].state == TrialState.COMPLETE
    # its neighbours (x ≈ 1: ~61) pull the lucky 80 far down
    assert shown[80].value is not None and shown[80].value < 75.0
    assert shown[running.number].state == TrialState.RUNNING and shown[running.number].value is None
    # every finished trial is valued at the reference step (3): the pruned ones lie on the same scale
    values = np.array([shown[t.number].value for t in study.trials[:80]])
    xs = np.array([t.params["x"] for t in study.trials[:80]])
    assert np.corrcoef(xs, values)[0, 1] > 0.9


def test_the_model_ranks_by_the_trend_better_than_the_noisy_scores() -> None:
    """Top tenth by the shown value against by the trial's own last score: the true x of the chosen ones."""
    study = _study(200, seed=3)
    shown = DenoisedSampler(optuna.samplers.RandomSampler(), 3, 0).shown(study)
    raw = [(t.intermediate_values[max(t.intermediate_values)], t.params["x"]) for t in study.trials]
    den = [(t.value, t.params["x"]) for t in shown]
    top_raw = np.mean([x for _, x in sorted(raw, reverse=True)[:20]])
    top_den = np.mean([x for _, x in sorted(den, reverse=True)[:20]])
    assert top_den > top_raw


def test_the_model_is_refitted_only_when_a_rung_finished() -> None:
    study = _study(40)
    sampler = DenoisedSampler(optuna.samplers.RandomSampler(), 3, 0)
    first = {t.number: t.value for t in sampler.shown(study)}
    assert {t.number: t.value for t in sampler.shown(study)} == first
    study.add_trial(create_trial(state=TrialState.PRUNED, params={"x": 9.0, "noise": 0.1}, distributions=DISTS,
                                 intermediate_values={1: 40.0}))  # fmt: skip
    after = {t.number: t.value for t in sampler.shown(study)}
    assert 40 in after and any(after[k] != v for k, v in first.items())


def test_tpe_behind_the_wrapper_climbs_the_trend() -> None:
    study = _study(60, seed=1)
    study.sampler = DenoisedSampler(optuna.samplers.TPESampler(seed=0, n_startup_trials=10, multivariate=True), 3, 0)
    for _ in range(20):
        trial = study.ask(DISTS)
        study.tell(trial, 60 + trial.params["x"])
    assert np.median([t.params["x"] for t in study.trials[60:]]) > 5.0


def test_the_spec_key_and_the_sampler_stack() -> None:
    assert _spec().study.denoise is False
    spec = _spec(denoise=True, balance=["method"])
    assert denoise_reference_step(spec) == 3  # min_top 1200 over the first rung 400
    gated = make_sampler(spec, 0, lambda _p: 1.0, lambda: 10.0)
    assert isinstance(gated, CostGatedSampler) and isinstance(gated.base, DenoisedSampler)
    assert isinstance(gated.base.base, BalancedSampler)
    assert not isinstance(make_sampler(_spec(), 0), DenoisedSampler)
    with pytest.raises(SpecError, match=r"\[study\] denoise: must be true or false, got 'yes'; write denoise = true"):
        _spec(denoise="yes")
    with pytest.raises(SpecError, match=r"\[study\] denoize: unknown key.*denoise"):
        _spec(denoize=True)


def test_the_quantile_key_reaches_the_sampler_and_bad_values_are_refused() -> None:
    assert _spec(denoise=True).study.denoise_quantile is None
    gated = make_sampler(_spec(denoise=True, denoise_quantile=0.9), 0, lambda _p: 1.0, lambda: 10.0)
    assert isinstance(gated, CostGatedSampler) and isinstance(gated.base, DenoisedSampler)
    assert gated.base.quantile == 0.9
    with pytest.raises(SpecError, match=r"denoise_quantile: must lie strictly between 0 and 1, got 1.0; e.g."):
        _spec(denoise=True, denoise_quantile=1)
    with pytest.raises(SpecError, match=r"denoise_quantile: needs denoise = true.*; add denoise = true"):
        _spec(denoise_quantile=0.9)
    with pytest.raises(ValueError, match="quantile must lie in"):
        DenoisedSampler(optuna.samplers.RandomSampler(), 3, 0, quantile=0.0)


def test_leaf_quantile_weighs_each_training_row_by_its_share_of_the_querys_leaves() -> None:
    rng = np.random.default_rng(0)
    train = rng.integers(0, 5, size=(40, 3))
    y = rng.normal(size=40)
    query = np.vstack([train[:6], [[0, 0, 0]]])
    for q in (0.1, 0.5, 0.9):
        got = leaf_quantile(train, y, query, q)
        for j, leaves in enumerate(query):
            w = np.zeros(len(y))
            for k in range(train.shape[1]):
                same = train[:, k] == leaves[k]
                if same.any():
                    w[same] += 1.0 / same.sum()
            order = np.argsort(y)
            cum = np.cumsum(w[order])
            assert got[j] == y[order][np.searchsorted(cum, q * cum[-1] - 1e-12)]


def test_an_upper_quantile_prefers_the_region_that_reaches_higher_at_the_same_mean() -> None:
    """x < 5: every training scores 70 ± 0.2; x ≥ 5: 70 ± 3. The mean shows them level, the 0.9 quantile lifts
    the varied region by about 1.28 sd."""
    rng = np.random.default_rng(4)
    study = optuna.create_study(direction="maximize")
    for _ in range(160):
        x = float(rng.uniform(0, 10))
        score = 70 + rng.normal(0, 0.2 if x < 5 else 3.0)
        study.add_trial(create_trial(state=TrialState.PRUNED, params={"x": x, "noise": 0.5}, distributions=DISTS,
                                     intermediate_values={1: score}))  # fmt: skip

    def gap(quantile: float | None) -> float:
        shown = DenoisedSampler(optuna.samplers.RandomSampler(), 1, 0, quantile=quantile).shown(study)
        varied = [t.value for t in shown if t.params["x"] >= 5]
        steady = [t.value for t in shown if t.params["x"] < 5]
        return float(np.median(varied) - np.median(steady))  # type: ignore[arg-type]

    assert abs(gap(None)) < 1.0
    assert gap(0.9) > 2.5


def test_a_denoised_study_of_the_real_space_draws_and_keeps_its_states() -> None:
    """Paper's space through the whole stack (gate, denoise, balance, TPE): draws stay inside the space."""
    spec = load_spec("study_configs/paper.toml")
    assert spec.study.denoise is True and spec.study.denoise_quantile == 0.9
    study = optuna.create_study(direction="maximize", sampler=make_sampler(spec, 0, lambda _p: 1.0, lambda: 10.0))
    rng = np.random.default_rng(0)
    for i in range(60):
        trial = study.ask()
        params = space.sample(trial, spec)
        score = 60 + params["other_agents"] + float(rng.normal(0, 2))
        trial.report(score, 1)
        if i % 3:
            study.tell(trial, state=TrialState.PRUNED)
        else:
            trial.report(score + 1, 3)
            study.tell(trial, score + 1)
    states = [t.state for t in study.trials]
    assert states.count(TrialState.PRUNED) == 40 and states.count(TrialState.COMPLETE) == 20
