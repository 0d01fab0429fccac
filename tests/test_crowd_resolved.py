"""All 164 crowd submissions resolve exactly as before the settings record (issue 13).

``tests/data/crowd_configs_resolved.json`` was written by the code at commit 455ea62, before the
change: for every submission its ``TrainConfig.to_mapping()`` and ``to_deepqlearn()``, the crowd
study's encoded params and the parameter count, or the reason the learner rejects it. The code of
today must give the same, row for row.
"""

from __future__ import annotations

import json
from typing import Any

import pytest

from dashboards import crowd
from dashboards import crowd_data as cd
from tests.conftest import ROOT

FIXTURE = ROOT / "tests" / "data" / "crowd_configs_resolved.json"


def _resolved(sub: cd.Submission) -> dict[str, Any]:
    rec: dict[str, Any] = {"id": sub.id}
    try:
        config = cd.train_config(sub)
    except cd.CrowdDataError as exc:
        rec["skip"] = str(exc)
        return rec
    rec["config"] = config.to_mapping()
    rec["deepqlearn"] = config.to_deepqlearn()
    rec["params"] = crowd.crowd_params(config)  # space.encode, as the crowd import uses it
    rec["param_count"] = config.param_count
    return json.loads(json.dumps(rec))  # tuples → lists, as the fixture holds them


def _diff(new: Any, old: Any, at: str = "") -> list[str]:
    """Where two JSON values differ, as 'path: new != old' lines."""
    if isinstance(new, dict) and isinstance(old, dict):
        return [d for k in sorted(set(new) | set(old)) for d in _diff(new.get(k), old.get(k), f"{at}.{k}")]
    if isinstance(new, list) and isinstance(old, list) and len(new) == len(old):
        return [d for i, (a, b) in enumerate(zip(new, old, strict=True)) for d in _diff(a, b, f"{at}[{i}]")]
    return [] if new == old else [f"{at}: {new!r} != {old!r}"]


@pytest.fixture(scope="module")
def pinned() -> dict[str, dict[str, Any]]:
    return {r["id"]: r for r in json.loads(FIXTURE.read_text(encoding="utf-8"))["submissions"]}


def test_every_submission_resolves_as_pinned(pinned: dict[str, dict[str, Any]]) -> None:
    subs = cd.load_submissions()
    assert [s.id for s in subs] == list(pinned) and len(subs) == 164
    different = {s.id: _diff(_resolved(s), pinned[s.id]) for s in subs if _resolved(s) != pinned[s.id]}
    assert different == {}, f"{len(different)} submission(s) resolve differently: {list(different.items())[:3]}"
    assert sum("skip" in r for r in pinned.values()) == 2
