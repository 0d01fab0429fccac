"""Read-only views of a study's trial records: summary, best trial, export of its network, retraining.

The records follow the team's trial contract (user attrs ``config``, ``settings``, ``seed``,
``curve``, ``frames_simulated``, ``official_*``, ``artifact_net_json`` / ``artifact_net_js``, …).
Everything here reads a storage opened by ``storage.open_storage``; nothing writes to it.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import optuna
from optuna.artifacts import download_artifact
from optuna.trial import FrozenTrial, TrialState

from autotune.search.storage import Storages, load_study
from sim.config import ConfigError

__all__ = [
    "RecordError",
    "Reproduction",
    "best_trial_record",
    "export_best",
    "export_trial",
    "rescore_trial",
    "retrain_trial",
    "study_summary",
    "trial_record",
]

FINISHED = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
_RECORD_ATTRS = (
    "source", "seed", "config", "settings", "input_size", "num_states", "param_count", "frames_simulated",
    "train_seconds", "eval_seconds", "official_protocol", "official_mean", "official_std", "diverged", "cause",
    "worker", "retry_of", "artifact_net_json", "artifact_net_js",
)  # fmt: skip


class RecordError(ConfigError):
    """A trial record that is missing or incomplete (no finished trial, no such number, no artifact)."""


def _iso(t: dt.datetime | None) -> str | None:
    return t.isoformat(timespec="seconds") if t is not None else None


def study_summary(storages: Storages, study_name: str) -> dict[str, Any]:
    """Counts by state, the best trial, and throughput over the study's wall span (JSON-ready).

    Throughput: finished trials (COMPLETE, PRUNED, FAIL) per hour and frames simulated per second
    (user attr ``frames_simulated``), both over the span from the first trial's start to the last
    finish — wall time of the whole study, all workers together, pauses between launches included.
    """
    study = load_study(storages, study_name)
    trials = study.get_trials(deepcopy=False)
    counts = {state.name: 0 for state in TrialState}
    for t in trials:
        counts[t.state.name] += 1
    finished = [t for t in trials if t.state in FINISHED]
    starts = [t.datetime_start for t in trials if t.datetime_start is not None]
    ends = [t.datetime_complete for t in finished if t.datetime_complete is not None]
    first = min(starts) if starts else None
    last = max(ends) if ends else None
    span = (last - first).total_seconds() if first is not None and last is not None else 0.0
    frames = sum(int(t.user_attrs.get("frames_simulated", 0) or 0) for t in finished)
    best = _best(study)
    best_out: dict[str, Any] | None = None
    if best is not None:
        reached = (best.datetime_complete - first).total_seconds() if best.datetime_complete and first else None
        best_out = {"number": best.number, "value": best.value, "params": best.params, "reached_s": reached}
    done = counts["COMPLETE"] + counts["PRUNED"]
    return {
        "study": study_name,
        "storage": storages.url,
        "direction": study.direction.name,
        "n_trials": len(trials),
        "states": counts,
        "prune_rate": counts["PRUNED"] / done if done else None,
        "best": best_out,
        "first_start": _iso(first),
        "last_finish": _iso(last),
        "wall_seconds": span,
        "trials_per_hour": len(finished) / span * 3600.0 if span > 0 else None,
        "frames_simulated": frames,
        "frames_per_second": frames / span if span > 0 else None,
    }


def _best(study: optuna.Study) -> FrozenTrial | None:
    try:
        return study.best_trial
    except ValueError:  # no COMPLETE trial yet
        return None


def _record(trial: FrozenTrial) -> dict[str, Any]:
    attrs = trial.user_attrs
    out: dict[str, Any] = {
        "number": trial.number,
        "state": trial.state.name,
        "value": trial.value,
        "params": trial.params,
        "datetime_start": _iso(trial.datetime_start),
        "datetime_complete": _iso(trial.datetime_complete),
        "duration_s": trial.duration.total_seconds() if trial.duration is not None else None,
    }
    out.update({k: attrs[k] for k in _RECORD_ATTRS if k in attrs})
    out["curve"] = attrs.get("curve", [])
    return out


def trial_record(storages: Storages, study_name: str, number: int) -> dict[str, Any]:
    """Trial ``number``'s record: state, value, params and the contract's user attrs (JSON-ready)."""
    return _record(_trial(load_study(storages, study_name), number))


def best_trial_record(storages: Storages, study_name: str) -> dict[str, Any]:
    """The best COMPLETE trial's record; ``RecordError`` when the study has none yet."""
    study = load_study(storages, study_name)
    best = _best(study)
    if best is None:
        raise RecordError(f"study '{study_name}' in '{storages.url}': no COMPLETE trial yet; nothing to show")
    return _record(best)


def _trial(study: optuna.Study, number: int) -> FrozenTrial:
    trials = study.get_trials(deepcopy=False)
    if not 0 <= number < len(trials):
        raise RecordError(
            f"study '{study.study_name}': no trial {number} (trials are numbered 0 … {len(trials) - 1})"
            if trials
            else f"study '{study.study_name}': no trial {number} (the study has no trials)"
        )
    trial = trials[number]
    assert trial.number == number
    return trial


def export_trial(storages: Storages, study_name: str, number: int, out_dir: str | Path) -> dict[str, Path]:
    """Write trial ``number``'s ``net.json``, ``net.config.json`` and ``net.js`` into ``out_dir``.

    The net comes from the trial's ``artifact_net_json`` artifact and ``net.js`` from
    ``artifact_net_js`` (regenerated from the net and settings when that one is absent);
    ``net.config.json`` is the net's DeepTraffic settings in the format ``autotune train`` writes
    (``write_net``), rebuilt from the trial's stored ``config``.
    """
    return _export(storages, _trial(load_study(storages, study_name), number), out_dir)


def export_best(storages: Storages, study_name: str, out_dir: str | Path) -> dict[str, Path]:
    """``export_trial`` of the best COMPLETE trial."""
    study = load_study(storages, study_name)
    best = _best(study)
    if best is None:
        raise RecordError(f"study '{study_name}' in '{storages.url}': no COMPLETE trial yet; nothing to export")
    return _export(storages, best, out_dir)


def _download(storages: Storages, trial: FrozenTrial, key: str) -> str | None:
    artifact_id = trial.user_attrs.get(key)
    if not artifact_id:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "artifact"
        try:
            download_artifact(artifact_store=storages.artifacts, file_path=str(path), artifact_id=str(artifact_id))
        except Exception as exc:  # the store raises its own not-found types
            raise RecordError(
                f"trial {trial.number}: artifact {key}={artifact_id} not found in {storages.artifact_dir} "
                f"({type(exc).__name__}); pass the study's --artifacts DIR"
            ) from None
        return path.read_text(encoding="utf-8")


def _export(storages: Storages, trial: FrozenTrial, out_dir: str | Path) -> dict[str, Path]:
    from autotune import TrainConfig, export_netjs, loads_net, write_net

    text = _download(storages, trial, "artifact_net_json")
    if text is None:
        raise RecordError(f"trial {trial.number}: no trained network stored (user attr artifact_net_json missing)")
    if "config" not in trial.user_attrs:
        raise RecordError(f"trial {trial.number}: no training config stored (user attr config missing)")
    net = loads_net(text, where=f"trial {trial.number} net.json")
    settings = TrainConfig.from_mapping(trial.user_attrs["config"]).settings
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"net.json": out / "net.json", "net.config.json": out / "net.config.json", "net.js": out / "net.js"}
    write_net(paths["net.json"], net, settings)  # net.json + net.config.json, as `autotune train` writes them
    netjs = _download(storages, trial, "artifact_net_js")
    paths["net.js"].write_text(netjs if netjs is not None else export_netjs(net, settings), encoding="utf-8")
    return paths


def format_summary(summary: dict[str, Any]) -> Sequence[str]:
    """``study_summary`` as the lines ``autotune status`` prints."""
    s = summary["states"]
    lines = [
        f"study {summary['study']} ({summary['storage']}): {summary['n_trials']} trials — "
        f"{s['COMPLETE']} complete, {s['PRUNED']} pruned, {s['FAIL']} failed, {s['RUNNING']} running, "
        f"{s['WAITING']} waiting"
    ]
    best = summary["best"]
    if best is None:
        lines.append("best: no complete trial yet")
    else:
        when = f" after {best['reached_s'] / 60:.1f} min" if best["reached_s"] is not None else ""
        lines.append(f"best: trial {best['number']}, {best['value']:.2f} mph{when}")
    if summary["trials_per_hour"] is not None:
        prune = f", prune rate {summary['prune_rate']:.0%}" if summary["prune_rate"] is not None else ""
        lines.append(
            f"throughput: {summary['trials_per_hour']:.1f} trials/h, {summary['frames_per_second']:,.0f} frames/s "
            f"over {summary['wall_seconds'] / 60:.1f} min ({summary['first_start']} → {summary['last_finish']}){prune}"
        )
    return lines


# --------------------------------------------------------------------------------------------
# reproducing a trial's score
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Reproduction:
    """A trial's stored official score next to the one obtained again (by re-scoring or retraining)."""

    study: str
    number: int
    stored: float
    """The trial's value: its official score as the study recorded it [mph]."""
    reproduced: float
    """The score obtained now [mph]."""
    protocol: str
    """The official protocol both scores come from."""
    seed: int
    """The trial's training seed."""
    how: str
    """``"rescore"`` (the stored net evaluated again) or ``"retrain"`` (trained again from the seed)."""
    wall_seconds: float
    """Time the reproduction took."""

    @property
    def identical(self) -> bool:
        """True when the scores are bit-identical (the objective is deterministic given the seed)."""
        return self.stored == self.reproduced

    def to_json(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "identical": self.identical}


def _complete_trial(storages: Storages, study_name: str, number: int) -> tuple[optuna.Study, FrozenTrial]:
    study = load_study(storages, study_name)
    trial = _trial(study, number)
    if trial.state != TrialState.COMPLETE or trial.value is None:
        raise RecordError(
            f"study '{study_name}': trial {number} is {trial.state.name}; only COMPLETE trials have an official "
            "score to reproduce"
        )
    for key in ("config", "seed"):
        if key not in trial.user_attrs:
            raise RecordError(f"study '{study_name}': trial {number} has no stored {key} (user attr '{key}')")
    return study, trial


def rescore_trial(storages: Storages, study_name: str, number: int) -> Reproduction:
    """Evaluate trial ``number``'s stored network again with its official protocol (exact, seconds)."""
    import time

    from autotune import TrainConfig, evaluate_official, loads_net, official_protocol

    _, trial = _complete_trial(storages, study_name, number)
    config = TrainConfig.from_mapping(trial.user_attrs["config"])
    protocol = str(trial.user_attrs.get("official_protocol") or official_protocol(config))
    text = _download(storages, trial, "artifact_net_json")
    if text is None:
        raise RecordError(f"trial {number}: no trained network stored (user attr artifact_net_json missing)")
    t0 = time.perf_counter()
    ev = evaluate_official(loads_net(text, where=f"trial {number} net.json"), config, protocol=protocol)
    assert trial.value is not None
    return Reproduction(
        study_name, number, float(trial.value), float(ev.median_site), protocol, int(trial.user_attrs["seed"]),
        "rescore", time.perf_counter() - t0,
    )  # fmt: skip


def retrain_trial(storages: Storages, study_name: str, number: int) -> Reproduction:
    """Train trial ``number`` again — its stored config and seed, the study's report settings — and score it.

    The call is the objective's own (``objective.run_trial`` with the task the driver built, never
    pruned, no time limit), so a deterministic learner gives the stored score bit for bit. The
    caller owns the process settings (``configure_process``) as a worker does.
    """
    import time

    from autotune.search.objective import COMPLETE, TrialTask, run_trial

    study, trial = _complete_trial(storages, study_name, number)
    evaluation = _evaluation(study)
    task = TrialTask(
        number=number,
        config=trial.user_attrs["config"],
        seed=int(trial.user_attrs["seed"]),
        report_points=int(evaluation.get("report_points", TrialTask.report_points)),
        quick_runs=int(evaluation.get("quick_runs", TrialTask.quick_runs)),
        quick_frames=int(evaluation.get("quick_frames", TrialTask.quick_frames)),
        final_protocol=str(trial.user_attrs.get("official_protocol") or evaluation.get("final_protocol") or ""),
        timeout_s=None,
    )
    t0 = time.perf_counter()
    outcome = run_trial(task, lambda step, frames, score: False)
    if outcome.state != COMPLETE or outcome.value is None:
        cause = (outcome.cause or "").strip().splitlines()
        raise RecordError(
            f"study '{study_name}': retraining trial {number} ended {outcome.state} ({cause[-1] if cause else '?'})"
        )
    assert trial.value is not None
    return Reproduction(
        study_name, number, float(trial.value), float(outcome.value), str(outcome.attrs["official_protocol"]),
        task.seed, "retrain", time.perf_counter() - t0,
    )  # fmt: skip


def _evaluation(study: optuna.Study) -> dict[str, Any]:
    """The [evaluation] table the study ran with (the driver stores the spec as study user attr ``spec``)."""
    spec = study.user_attrs.get("spec")
    evaluation = spec.get("evaluation") if isinstance(spec, dict) else None
    return evaluation if isinstance(evaluation, dict) else {}


def study_resources(storages: Storages, study_name: str) -> dict[str, Any]:
    """The [resources] table the study ran with ({} when the study has no stored spec)."""
    spec = load_study(storages, study_name).user_attrs.get("spec")
    resources = spec.get("resources") if isinstance(spec, dict) else None
    return resources if isinstance(resources, dict) else {}


def race_summary(storages: Storages, study_name: str) -> dict[str, Any] | None:
    """The seed race's standings (``autotune.search.racing``): each entrant's fresh-seed mean ± sd and n.

    None when the study has not raced. The winner is the entrant with the most fresh seeds, then the best
    mean: the configuration to retrain, as opposed to the best single net (the leaderboard's number).
    """
    from autotune.search import racing

    study = load_study(storages, study_name)
    field = study.user_attrs.get("race_field")
    if not field:
        return None
    trials = study.get_trials(deepcopy=False)
    results: dict[tuple[int, int], float | None] = {}
    for t in trials:
        if "race_of" in t.user_attrs and t.state == TrialState.COMPLETE and t.value is not None:
            results[(int(t.user_attrs["race_of"]), int(t.user_attrs["race_seed"]))] = float(t.value)
    rows = []
    for st in racing.standings([int(n) for n in field], results):
        rows.append({"trial": st.number, "selecting_value": trials[st.number].value, "n": len(st.scores),
                     "mean": st.mean if st.scores else None, "sd": st.sd if len(st.scores) > 1 else None,
                     "scores": list(st.scores)})  # fmt: skip
    return {"entrants": [int(n) for n in field], "standings": rows, "winner": rows[0] if rows[0]["n"] else None}
