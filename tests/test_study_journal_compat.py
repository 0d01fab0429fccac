"""Study journals already written still open and read the same.

``tests/data/study_journal/journal.log.gz`` was written by the code of commit 455ea62 (before the search
core and the commands were reorganised): ``autotune launch study_configs/smoke.toml`` (4 trials: 3
complete, 1 pruned, nets as artifacts), then ``autotune crowd import`` and ``autotune crowd replay
--enqueue-only`` (2 settings × 2 seeds, WAITING) into the same journal. ``expected.json.gz`` holds what
the code before the reorganisation (main at 2d3a45e) printed for ``status``/``best`` and read as trial
records and report data from it — the same as 455ea62's own reading but for what issues 14 and 15 added
on purpose (the seed-race line of ``best``, the provenance of every report point) —; today's code must
read the same.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gzip
import io
import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from autotune import cli
from autotune.search.records import read_study, trial_record
from autotune.search.storage import open_storage
from dashboards import extract
from tests.conftest import ROOT, load_json

FIXTURE = ROOT / "tests" / "data" / "study_journal"
EXPECTED = load_json(FIXTURE / "expected.json.gz")
STUDIES = ("smoke", "crowd", "crowd-replay")


@pytest.fixture(scope="module")
def journal(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A writable copy of the fixture journal (relative path, as the expected output names it)."""
    root = tmp_path_factory.mktemp("journal")
    run_dir = root / "runs" / "smoke"
    run_dir.mkdir(parents=True)
    with gzip.open(FIXTURE / "journal.log.gz", "rb") as src, (run_dir / "journal.log").open("wb") as dst:
        shutil.copyfileobj(src, dst)
    shutil.copytree(FIXTURE / "artifacts", run_dir / "artifacts")
    return str(run_dir / "journal.log")


def _run(argv: list[str], journal: str) -> dict[str, Any]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main([*argv, "--storage", journal])
    return {"rc": rc, "stdout": out.getvalue(), "stderr": err.getvalue()}


@pytest.mark.parametrize("command", sorted(EXPECTED["commands"]))
def test_status_and_best_print_the_same(journal: str, command: str) -> None:
    expected = {k: v.replace("{storage}", journal) if isinstance(v, str) else v
                for k, v in EXPECTED["commands"][command].items()}  # fmt: skip
    assert _run(command.split(), journal) == expected


@pytest.mark.parametrize("name", STUDIES)
def test_trial_records_read_the_same(journal: str, name: str) -> None:
    storages = open_storage(journal, "smoke", heartbeat=False, create=False)
    study = read_study(storages, name)
    assert [trial_record(storages, name, t.number) for t in study.trials] == EXPECTED["records"][name]


@pytest.mark.parametrize("name", STUDIES)
def test_report_data_reads_the_same(journal: str, name: str) -> None:
    study = read_study(open_storage(journal, "smoke", heartbeat=False, create=False), name)
    data = json.loads(json.dumps(dataclasses.asdict(extract.study_data(study)), default=str))
    data["direction"] = study.direction
    assert data == EXPECTED["study_data"][name]


def test_the_fixture_has_every_kind_of_trial() -> None:
    """The journal covers what readers meet: complete and pruned trials with nets, imported and enqueued ones."""
    states = {name: sorted({r["state"] for r in EXPECTED["records"][name]}) for name in STUDIES}
    assert states == {"smoke": ["COMPLETE", "PRUNED"], "crowd": ["COMPLETE"], "crowd-replay": ["WAITING"]}
    assert sum(1 for r in EXPECTED["records"]["smoke"] if "artifact_net_json" in r) == 3
    assert Path(FIXTURE / "artifacts").is_dir() and len(list((FIXTURE / "artifacts").iterdir())) == 6


def _types(value: Any) -> set[str]:
    """The modules of every object inside ``value`` (dataclasses, mappings and sequences walked)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        inner = [getattr(value, f.name) for f in dataclasses.fields(value)]
    elif isinstance(value, dict):
        inner = [*value.keys(), *value.values()]
    elif isinstance(value, (list, tuple)):
        inner = list(value)
    else:
        inner = []
    return {type(value).__module__}.union(*(_types(v) for v in inner))


def test_the_read_api_hands_out_plain_data(journal: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """What ``dashboards`` and the commands get: records of builtins, datetimes and records — no Optuna object."""
    from autotune.search.records import find_study

    for name in STUDIES:
        study = read_study(open_storage(journal, "smoke", heartbeat=False, create=False), name)
        assert not [m for m in _types(study) if m.split(".")[0] in ("optuna", "optuna_dashboard")]
    assert read_study(open_storage(journal, "smoke", heartbeat=False), "smoke").best_number == 3
    assert find_study(journal, "crowd") is not None and find_study(journal, "nope") is None
    monkeypatch.chdir(tmp_path)
    assert find_study("", "nope") is None and not (tmp_path / "runs").exists()  # finding creates nothing
