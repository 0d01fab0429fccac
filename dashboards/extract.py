"""Plot data extracted from Optuna studies (automated or crowd), as plain frozen dataclasses of lists.

Everything a report panel shows is computed here and tested as values; ``dashboards.figures``
only draws it. A panel that cannot be computed (too few trials, a constant setting) gets an
``Empty`` with the reason, which the report prints instead of an empty figure.
Trials are read through the trial-record contract: the value is the official score, the real
settings are in the ``config`` user attribute (parameters, in sampling coordinates, are the
fallback), and the compute spent is ``frames_simulated``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import optuna

__all__ = [
    "HYPERPARAMETERS",
    "LOG_AXES",
    "Empty",
    "TrialPoint",
    "StudyData",
    "Series",
    "SizeScatter",
    "Panel",
    "TsneMap",
    "Importances",
    "ReplayRow",
    "study_data",
    "progress",
    "size_scatter",
    "hyperparameter_panels",
    "compute_curve",
    "tsne_map",
    "importances",
    "replay_comparison",
    "own_net_comparison",
]

# the paper's per-hyperparameter panels, in the order (real values, not sampling coordinates)
HYPERPARAMETERS = (
    "lanes_side",
    "patches_ahead",
    "patches_behind",
    "temporal_window",
    "other_agents",
    "gamma",
    "learning_rate",
    "l2_decay",
    "batch_size",
    "experience_size",
    "train_iterations",
)
LOG_AXES = frozenset({"learning_rate", "batch_size", "experience_size", "train_iterations"})
FINISHED = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED, optuna.trial.TrialState.FAIL)


@dataclasses.dataclass(frozen=True)
class Empty:
    """A panel with nothing to draw, and why (shown to the reader instead of a figure)."""

    reason: str


@dataclasses.dataclass(frozen=True)
class TrialPoint:
    """One finished trial as the report reads it."""

    number: int
    """Optuna trial number (the crowd: submission order)."""
    state: str
    """COMPLETE, PRUNED or FAIL."""
    value: float | None
    """Official (crowd: self-reported) score [mph]; None unless COMPLETE with a finite value."""
    label: str
    """Hover label: the crowd id, else 'trial N'."""
    settings: dict[str, float]
    """Real values of ``HYPERPARAMETERS`` present in the trial."""
    param_count: int | None
    """Weights + biases of the trial's net."""
    n_layers: int | None
    """Hidden layers with neurons."""
    frames: int | None
    """Frames simulated for the trial (training + evaluation; the crowd: 30·trainIterations)."""
    crowd_id: str | None
    """The crowd submission the trial replays or records."""


@dataclasses.dataclass(frozen=True)
class StudyData:
    """A study's finished trials in trial order, with its name and source ('autotune' or 'crowd')."""

    name: str
    source: str
    trials: tuple[TrialPoint, ...]
    user_attrs: dict[str, Any]

    @property
    def scored(self) -> list[TrialPoint]:
        """Trials with a score."""
        return [t for t in self.trials if t.value is not None]


@dataclasses.dataclass(frozen=True)
class Series:
    """Score in trial order with the running best (the paper's progress figure)."""

    order: list[int]
    score: list[float]
    best: list[float]
    labels: list[str]


@dataclasses.dataclass(frozen=True)
class SizeScatter:
    """Parameter count against score, with the layer count and training iterations for colouring."""

    param_count: list[int]
    score: list[float]
    n_layers: list[int]
    train_iterations: list[float]
    labels: list[str]


@dataclasses.dataclass(frozen=True)
class Panel:
    """One hyperparameter against score."""

    name: str
    x: list[float]
    score: list[float]
    labels: list[str]
    log_x: bool


@dataclasses.dataclass(frozen=True)
class TsneMap:
    """A joint 2-D t-SNE embedding of both studies' settings (standardised, log-scaled where wide)."""

    x: list[float]
    y: list[float]
    score: list[float]
    source: list[str]
    labels: list[str]
    features: list[str]
    seed: int


@dataclasses.dataclass(frozen=True)
class Importances:
    """Hyperparameter importances of a study (normalised to sum 1), largest first."""

    names: list[str]
    values: list[float]
    evaluator: str


@dataclasses.dataclass(frozen=True)
class ReplayRow:
    """A crowd setting: its self-reported score against our measured score(s)."""

    crowd_id: str
    reported: float
    measured: float
    std: float
    n: int


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def _settings(trial: optuna.trial.FrozenTrial) -> dict[str, float]:
    config = trial.user_attrs.get("config")
    source: dict[str, Any] = dict(config) if isinstance(config, dict) else {}
    for name in HYPERPARAMETERS:
        if name not in source and name in trial.params:
            source[name] = trial.params[name]
    if "gamma" not in source and "one_minus_gamma" in trial.params:
        source["gamma"] = 1.0 - trial.params["one_minus_gamma"]
    if source.get("ruleset") == "v1":
        source.pop("other_agents", None)  # v1 has no agents: not "0 agents"
    out = {}
    for name in HYPERPARAMETERS:
        value = _number(source.get(name))
        if value is not None:
            out[name] = value
    return out


def _n_layers(trial: optuna.trial.FrozenTrial) -> int | None:
    if "n_layers" in trial.params:
        return int(trial.params["n_layers"])
    config = trial.user_attrs.get("config")
    if isinstance(config, dict) and isinstance(config.get("layers"), str):
        return sum(1 for part in config["layers"].split("|") if part and not part.startswith("lrn"))
    return None


def study_data(study: optuna.Study) -> StudyData:
    """The finished trials of ``study`` (COMPLETE, PRUNED, FAIL) as ``TrialPoint``s, in trial order."""
    if study.direction != optuna.study.StudyDirection.MAXIMIZE:
        raise ValueError(f"study {study.study_name!r} minimizes; reports compare scores (maximized)")
    points = []
    for t in study.get_trials(deepcopy=False, states=FINISHED):
        value = _number(t.value) if t.state == optuna.trial.TrialState.COMPLETE else None
        attrs = t.user_attrs
        crowd_id = attrs.get("crowd_id")
        pc = _number(attrs.get("param_count"))
        frames = _number(attrs.get("frames_simulated"))
        points.append(
            TrialPoint(
                number=t.number,
                state=t.state.name,
                value=value,
                label=str(crowd_id) if crowd_id and attrs.get("source") == "crowd" else f"trial {t.number}",
                settings=_settings(t),
                param_count=int(pc) if pc is not None else None,
                n_layers=_n_layers(t),
                frames=int(frames) if frames is not None else None,
                crowd_id=str(crowd_id) if crowd_id else None,
            )
        )
    sources = {t.user_attrs.get("source") for t in study.get_trials(deepcopy=False)}
    source = str(study.user_attrs.get("source") or (sources.pop() if len(sources) == 1 else "autotune") or "autotune")
    return StudyData(study.study_name, source, tuple(points), dict(study.user_attrs))


def progress(data: StudyData) -> Series | Empty:
    """Scores in trial (crowd: submission) order with the running best."""
    scored = data.scored
    if not scored:
        return Empty(f"{data.name}: no scored trial yet")
    best: list[float] = []
    for t in scored:
        best.append(max(best[-1], t.value) if best else t.value)  # type: ignore[type-var,arg-type]
    return Series(
        order=[t.number for t in scored],
        score=[float(t.value) for t in scored],  # type: ignore[arg-type]
        best=best,
        labels=[t.label for t in scored],
    )


def size_scatter(data: StudyData) -> SizeScatter | Empty:
    """Parameter count against score (trials that record both)."""
    pts = [t for t in data.scored if t.param_count is not None]
    if not pts:
        return Empty(f"{data.name}: no scored trial records its parameter count")
    return SizeScatter(
        param_count=[int(t.param_count) for t in pts],  # type: ignore[arg-type]
        score=[float(t.value) for t in pts],  # type: ignore[arg-type]
        n_layers=[t.n_layers if t.n_layers is not None else -1 for t in pts],
        train_iterations=[t.settings.get("train_iterations", math.nan) for t in pts],
        labels=[t.label for t in pts],
    )


def hyperparameter_panels(data: StudyData) -> dict[str, Panel | Empty]:
    """One panel per hyperparameter of ``HYPERPARAMETERS``: its real value against score."""
    out: dict[str, Panel | Empty] = {}
    for name in HYPERPARAMETERS:
        pts = [t for t in data.scored if name in t.settings]
        if not pts:
            out[name] = Empty(f"{data.name}: {name} not recorded in any scored trial")
            continue
        out[name] = Panel(
            name=name,
            x=[t.settings[name] for t in pts],
            score=[float(t.value) for t in pts],  # type: ignore[arg-type]
            labels=[t.label for t in pts],
            log_x=name in LOG_AXES and all(t.settings[name] > 0 for t in pts),
        )
    return out


def compute_curve(data: StudyData) -> Series | Empty:
    """Best score against cumulative frames simulated (every finished trial's frames count; order = trial order).

    ``order`` holds the cumulative frames after each trial; trials that record no frames are left out.
    """
    frames = 0
    order: list[int] = []
    best: list[float] = []
    score: list[float] = []
    labels: list[str] = []
    for t in data.trials:
        if t.frames is None:
            continue
        frames += t.frames
        current = best[-1] if best else -math.inf
        if t.value is not None:
            current = max(current, t.value)
        if current == -math.inf:
            continue  # nothing scored yet: no best to draw
        order.append(frames)
        best.append(current)
        score.append(t.value if t.value is not None else math.nan)
        labels.append(t.label)
    if not order:
        return Empty(f"{data.name}: no scored trial records frames_simulated")
    return Series(order=order, score=score, best=best, labels=labels)


def _feature_matrix(points: Sequence[TrialPoint], features: Sequence[str]) -> np.ndarray:
    rows = []
    for t in points:
        row = []
        for name in features:
            v = t.settings.get(name, math.nan) if name != "param_count" else float(t.param_count or math.nan)
            if name in LOG_AXES or name == "param_count":
                v = math.log10(v) if v > 0 else math.nan
            row.append(v)
        rows.append(row)
    x = np.asarray(rows, dtype=float)
    med = np.nanmedian(np.where(np.isnan(x), np.nan, x), axis=0) if len(x) else np.zeros(len(features))
    x = np.where(np.isnan(x), np.nan_to_num(med)[None, :], x)
    std = x.std(axis=0)
    std[std == 0] = 1.0
    return (x - x.mean(axis=0)) / std


def tsne_map(studies: Sequence[StudyData], seed: int = 0, min_points: int = 5) -> TsneMap | Empty:
    """Joint t-SNE (sklearn, ``random_state=seed``) of every scored trial's settings, coloured by score.

    Features: the hyperparameters that vary across the points, plus log10 parameter count; missing
    values take the column's median (e.g. v1 rows have no other_agents).
    """
    points = [(d.source, t) for d in studies for t in d.scored]
    if len(points) < min_points:
        return Empty(f"t-SNE needs at least {min_points} scored trials; there are {len(points)}")
    features = [
        name
        for name in (*HYPERPARAMETERS, "param_count")
        if len({t.settings.get(name) if name != "param_count" else t.param_count for _s, t in points}) > 1
    ]
    if not features:
        return Empty("t-SNE: every scored trial has the same settings")
    from sklearn.manifold import TSNE

    x = _feature_matrix([t for _s, t in points], features)
    perplexity = float(min(30.0, (len(points) - 1) / 3.0))
    emb = TSNE(n_components=2, perplexity=perplexity, random_state=seed, init="pca").fit_transform(x)
    return TsneMap(
        x=[float(v) for v in emb[:, 0]],
        y=[float(v) for v in emb[:, 1]],
        score=[float(t.value) for _s, t in points],  # type: ignore[arg-type]
        source=[s for s, _t in points],
        labels=[t.label for _s, t in points],
        features=features,
        seed=seed,
    )


def importances(study: optuna.Study, seed: int = 0, min_trials: int = 4) -> Importances | Empty:
    """Optuna's fANOVA importances (``seed`` fixed) over the parameters every COMPLETE trial shares."""
    complete = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    if len(complete) < min_trials:
        return Empty(
            f"{study.study_name}: importances need at least {min_trials} complete trials, have {len(complete)}"
        )
    shared = set.intersection(*(set(t.params) for t in complete))
    varying = sorted(p for p in shared if len({repr(t.params[p]) for t in complete}) > 1)
    if not varying:
        return Empty(f"{study.study_name}: no parameter varies across its complete trials")
    if len({t.value for t in complete}) < 2:
        return Empty(f"{study.study_name}: every complete trial has the same score")
    evaluator = optuna.importance.FanovaImportanceEvaluator(seed=seed)
    result = optuna.importance.get_param_importances(study, evaluator=evaluator, params=varying)
    ranked = sorted(result.items(), key=lambda kv: (-kv[1], kv[0]))
    return Importances([k for k, _ in ranked], [float(v) for _, v in ranked], f"fANOVA (seed {seed})")


def replay_comparison(replay: StudyData, crowd_scores: dict[str, float]) -> list[ReplayRow] | Empty:
    """Per replayed crowd setting: self-reported score against the mean of our seeds' official scores."""
    runs: dict[str, list[float]] = {}
    for t in replay.scored:
        if t.crowd_id is not None and t.crowd_id in crowd_scores:
            runs.setdefault(t.crowd_id, []).append(float(t.value))  # type: ignore[arg-type]
    if not runs:
        return Empty(f"{replay.name}: no replayed crowd setting has finished with a score")
    return [
        ReplayRow(
            crowd_id=cid,
            reported=crowd_scores[cid],
            measured=float(np.mean(v)),
            std=float(np.std(v, ddof=1)) if len(v) > 1 else 0.0,
            n=len(v),
        )
        for cid, v in sorted(runs.items())
    ]


def own_net_comparison(crowd: StudyData) -> list[ReplayRow] | Empty:
    """The human nets scored with their own weights (study attr ``own_net_scores``) against their reported scores."""
    own = crowd.user_attrs.get("own_net_scores") or {}
    reported = {t.crowd_id: t.value for t in crowd.scored if t.crowd_id}
    rows = [
        ReplayRow(cid, float(reported[cid]), float(v["score"]), float(v.get("std", 0.0)), int(v.get("runs", 1)))  # type: ignore[arg-type]
        for cid, v in sorted(own.items())
        if cid in reported and _number(v.get("score")) is not None
    ]
    if not rows:
        return Empty(f"{crowd.name}: the human nets have not been scored yet (autotune crowd import --own-nets)")
    return rows
