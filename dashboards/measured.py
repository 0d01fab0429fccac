"""The measured crowd, shipped as package data: the human nets' own-weight scores and the crowd replay table.

Two JSON files under ``data/crowd/`` that the report reads without running anything, each holding
the command that regenerates it:

* ``own_nets.json`` — the 25 human nets (``nets/``) scored with their own trained weights, in
  their own engine, with that engine's official protocol and seed (exact and deterministic:
  ``score_own_nets`` gives the same numbers on every machine);
* ``replay.json`` — crowd configurations retrained by our learner in their own engine, several
  seeds each, beside the score their authors claimed (``replay_selection`` picks them; the
  training runs in ``tools/crowd_measurements.py replay``). Absent until someone runs it.

Loading validates every field and fails with ``MeasuredDataError`` naming the file, the entry and
the key. Scoring uses the exact evaluator (numba; no torch, no ray).
"""

from __future__ import annotations

import dataclasses
import json
import math
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from dashboards import crowd_data as cd
from sim.config import ConfigError

__all__ = [
    "OWN_NETS_FILE",
    "REPLAY_FILE",
    "OWN_NETS_COMMAND",
    "REPLAY_COMMAND",
    "MeasuredDataError",
    "OwnNetScore",
    "ReplayRun",
    "ReplayEntry",
    "ReplayTable",
    "score_own_net",
    "score_own_nets",
    "own_nets_document",
    "load_own_nets",
    "replay_selection",
    "replay_document",
    "load_replay",
    "write_document",
]

FORMAT = 1
OWN_NETS_FILE = "own_nets.json"
REPLAY_FILE = "replay.json"
OWN_NETS_COMMAND = "python tools/crowd_measurements.py own-nets"
REPLAY_COMMAND = "python tools/crowd_measurements.py replay --workers N"
REPLAY_V2, REPLAY_V1, REPLAY_SEEDS = 20, 15, 2  # the shipped table's selection: best-claimed per engine, seeds each


class MeasuredDataError(ConfigError):
    """A shipped measurement file that is missing a key, has a bad value, or is not JSON."""


@dataclasses.dataclass(frozen=True)
class OwnNetScore:
    """A human net scored with its own weights: the site's statistic of its engine's official protocol."""

    crowd_id: str
    """The submission (``submissions.csv`` id; its net is ``nets/<id>.json``)."""
    engine: str
    """Engine the net was trained for and is scored in ('v1' or 'v2')."""
    other_agents: int | None
    """Other agents on the road while scored (the net's own otherAgents; None in v1, which has none)."""
    protocol: str
    """Official protocol of the engine (v2-official, v1-original)."""
    seed: int
    """The protocol's Math.random seed (its own: 1 for v2-official, 2000 for v1-original)."""
    runs: int
    """Evaluation runs."""
    frames: int
    """Frames per run."""
    score: float
    """The site's statistic: the lexicographic median of the per-run scores [mph]."""
    mean: float
    """Mean of the per-run scores [mph]."""
    std: float
    """Sample standard deviation of the per-run scores [mph]."""
    claimed: float
    """The score the author reported [mph]."""
    claim_kind: str
    """The report's kind (``score_kind``: claimed, local, approx, official-example)."""
    claim_confidence: str
    """How surely the report belongs to this file (``score_confidence``)."""
    seconds: float
    """Wall time of the evaluation when the file was made [s] (informative; not part of the result)."""


def score_own_net(crowd_id: str) -> OwnNetScore:
    """Score one packaged net with its own weights, engine and official protocol (fresh Gaussian cache)."""
    from autotune.learner.brain_policy import evaluate_net
    from sim.protocols import OFFICIAL

    sub = _submission(crowd_id)
    net, settings = cd.load_net(crowd_id)
    protocol = OFFICIAL[settings.engine]
    t0 = time.perf_counter()
    result = evaluate_net(net, settings, protocol)
    seconds = time.perf_counter() - t0
    assert sub.reported_score_mph is not None and sub.score_kind is not None and sub.score_confidence is not None
    return OwnNetScore(
        crowd_id=crowd_id,
        engine=settings.engine,
        other_agents=result.other_agents if settings.engine == "v2" else None,
        protocol=protocol,
        seed=result.seed,
        runs=result.runs,
        frames=result.frames,
        score=result.median_site,
        mean=result.mean,
        std=result.std,
        claimed=sub.reported_score_mph,
        claim_kind=sub.score_kind,
        claim_confidence=sub.score_confidence,
        seconds=round(seconds, 2),
    )


def score_own_nets(
    ids: Sequence[str] | None = None, progress: Callable[[OwnNetScore], None] | None = None
) -> list[OwnNetScore]:
    """Score the packaged nets (default: all 25, sorted by id), calling ``progress`` after each."""
    out = []
    for nid in cd.net_ids() if ids is None else ids:
        scored = score_own_net(nid)
        out.append(scored)
        if progress is not None:
            progress(scored)
    return out


def _submission(crowd_id: str) -> cd.Submission:
    for sub in cd.load_submissions():
        if sub.id == crowd_id:
            return sub
    raise MeasuredDataError(f"crowd id {crowd_id!r} is not in submissions.csv")


def own_nets_document(scores: Sequence[OwnNetScore]) -> dict[str, Any]:
    """The JSON document of ``own_nets.json``."""
    return {
        "format": FORMAT,
        "what": "the human nets scored with their own trained weights, in their own engine, with that engine's "
        "official protocol and seed (exact evaluator; deterministic)",
        "command": OWN_NETS_COMMAND,
        "seconds": round(sum(s.seconds for s in scores), 1),
        "nets": [dataclasses.asdict(s) for s in scores],
    }


def write_document(document: dict[str, Any], path: Path) -> Path:
    """Write a document atomically (a temporary file renamed over ``path``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(document, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    tmp.replace(path)
    return path


def _read(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise MeasuredDataError(f"{path}: cannot read ({exc.strerror})") from None
    except ValueError as exc:
        raise MeasuredDataError(f"{path}: not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise MeasuredDataError(f"{path}: not a format-{FORMAT} measurement file")
    return doc


_TYPES: dict[type, tuple[type, ...]] = {float: (int, float), int: (int,), str: (str,)}


def _typed(cls: type, entry: Any, where: str) -> Any:
    """A dataclass from a JSON object, every field present and of its annotated type."""
    if not isinstance(entry, dict):
        raise MeasuredDataError(f"{where}: not an object")
    values: dict[str, Any] = {}
    for field in dataclasses.fields(cls):
        if field.name not in entry:
            raise MeasuredDataError(f"{where}: missing key '{field.name}'")
        value = entry[field.name]
        kinds = str(field.type).replace(" ", "").split("|")
        if value is None and "None" in kinds:
            values[field.name] = None
            continue
        base = {"float": float, "int": int, "str": str}.get(kinds[0])
        if base is not None:
            ok = isinstance(value, _TYPES[base]) and not isinstance(value, bool)
            if ok and base is float and not math.isfinite(value):
                ok = False
            if not ok:
                raise MeasuredDataError(f"{where}, key '{field.name}': {value!r} is not a {kinds[0]}")
        values[field.name] = float(value) if base is float else value
    return cls(**values)


def load_own_nets(path: Path | None = None) -> tuple[OwnNetScore, ...]:
    """The shipped own-net scores (default: the package's ``own_nets.json``), validated."""
    path = cd.data_dir() / OWN_NETS_FILE if path is None else path
    doc = _read(path)
    nets = doc.get("nets")
    if not isinstance(nets, list):
        raise MeasuredDataError(f"{path}: missing key 'nets' (a list)")
    return tuple(_typed(OwnNetScore, entry, f"{path}: nets[{i}]") for i, entry in enumerate(nets))


# --- the crowd replay table -------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ReplayRun:
    """One training seed of a replayed configuration."""

    seed_index: int
    """k: the k-th seed of the configuration (``crowd_replay.replay_seed`` gives the training seed)."""
    seed: int
    """Training seed."""
    state: str
    """complete, pruned or failed (the trial objective's outcome)."""
    score: float | None
    """The site's statistic of the official protocol [mph]; None unless complete."""
    seconds: float
    """Wall time of training and evaluation [s]."""
    cause: str | None
    """Why it did not complete (None when complete)."""


@dataclasses.dataclass(frozen=True)
class ReplayEntry:
    """A crowd configuration (identical settings once) retrained by our learner, beside its claimed score."""

    crowd_id: str
    """The row whose settings were trained (the best-claimed row of its configuration)."""
    config_hash: str
    """The configuration (``submissions.csv`` config_hash)."""
    rows: tuple[str, ...]
    """Every scored row with this configuration."""
    engine: str
    """Engine of the configuration, trained and scored in it."""
    other_agents: int | None
    """Other agents while training and scoring (None in v1)."""
    protocol: str
    """Official protocol of the engine."""
    train_iterations: int
    """Training iterations used (the submission's own unless the table was made with a cap)."""
    claimed: float
    """The best claimed score of the configuration [mph]."""
    claim_kind: str
    """Its kind (``score_kind``)."""
    claim_confidence: str
    """Its confidence (``score_confidence``)."""
    runs: tuple[ReplayRun, ...]
    """One entry per seed."""

    @property
    def scores(self) -> list[float]:
        """Scores of the complete seeds [mph]."""
        return [r.score for r in self.runs if r.score is not None]

    @property
    def mean(self) -> float | None:
        """Mean over complete seeds [mph]."""
        return statistics.fmean(self.scores) if self.scores else None

    @property
    def sd(self) -> float | None:
        """Sample standard deviation over complete seeds (None below 2) [mph]."""
        return statistics.stdev(self.scores) if len(self.scores) > 1 else None

    @property
    def seconds(self) -> float:
        """Wall time of all its seeds [s]."""
        return sum(r.seconds for r in self.runs)


@dataclasses.dataclass(frozen=True)
class ReplayTable:
    """The shipped replay table and how it was made."""

    command: str
    seeds: int
    max_iterations: int | None
    """Cap on training iterations (None: each configuration's own, the honest replay)."""
    entries: tuple[ReplayEntry, ...]


def replay_selection(n_v2: int = REPLAY_V2, n_v1: int = REPLAY_V1) -> list[list[cd.Submission]]:
    """The best-claimed configurations of each engine (v2 first), identical settings once.

    A configuration is a ``config_hash``; its rows are the scored rows that share it, best claim
    first (the one trained). Configurations our learner refuses are left out; ties on the claim go
    to the earlier row in the file.
    """
    groups: dict[str, list[cd.Submission]] = {}
    for sub in cd.load_submissions():
        if sub.reported_score_mph is None:
            continue
        try:
            cd.train_config(sub)
        except cd.CrowdDataError:
            continue
        groups.setdefault(sub.config_hash, []).append(sub)
    out: list[list[cd.Submission]] = []
    for engine, n in (("v2", n_v2), ("v1", n_v1)):
        mine = [sorted(g, key=lambda s: -(s.reported_score_mph or 0.0)) for g in groups.values()]
        mine = [g for g in mine if g[0].engine_version == engine]
        mine.sort(key=lambda g: -(g[0].reported_score_mph or 0.0))  # stable: file order among ties
        out += mine[:n]
    return out


def replay_document(table: ReplayTable) -> dict[str, Any]:
    """The JSON document of ``replay.json``."""
    entries = []
    for e in table.entries:
        entry = dataclasses.asdict(e)
        entry["rows"] = list(e.rows)
        entry["runs"] = [dataclasses.asdict(r) for r in e.runs]
        entry.update(mean=e.mean, sd=e.sd, n=len(e.scores), seconds=round(e.seconds, 1))
        entries.append(entry)
    return {
        "format": FORMAT,
        "what": "crowd configurations (identical settings once) retrained by our learner in their own engine and "
        "scored with its official protocol, beside the best claimed score of the configuration",
        "command": table.command,
        "seeds": table.seeds,
        "max_iterations": table.max_iterations,
        "seconds": round(sum(e.seconds for e in table.entries), 1),
        "entries": entries,
    }


def load_replay(path: Path | None = None) -> ReplayTable | None:
    """The shipped replay table (default: the package's ``replay.json``); None when the file does not exist."""
    path = cd.data_dir() / REPLAY_FILE if path is None else path
    if not path.exists():
        return None
    doc = _read(path)
    raw = doc.get("entries")
    if not isinstance(raw, list):
        raise MeasuredDataError(f"{path}: missing key 'entries' (a list)")
    entries = []
    for i, entry in enumerate(raw):
        where = f"{path}: entries[{i}]"
        if not isinstance(entry, dict):
            raise MeasuredDataError(f"{where}: not an object")
        runs = entry.get("runs")
        rows = entry.get("rows")
        if not isinstance(runs, list) or not isinstance(rows, list) or not all(isinstance(r, str) for r in rows):
            raise MeasuredDataError(f"{where}: 'runs' must be a list of runs and 'rows' a list of ids")
        parsed_runs = tuple(_typed(ReplayRun, r, f"{where}: runs[{k}]") for k, r in enumerate(runs))
        base = _typed(ReplayEntry, {**entry, "runs": (), "rows": ()}, where)
        entries.append(dataclasses.replace(base, runs=parsed_runs, rows=tuple(rows)))
    seeds, cap = doc.get("seeds"), doc.get("max_iterations")
    if not isinstance(seeds, int) or not (cap is None or isinstance(cap, int)):
        raise MeasuredDataError(f"{path}: 'seeds' must be an integer and 'max_iterations' an integer or null")
    return ReplayTable(str(doc.get("command", "")), seeds, cap, tuple(entries))
