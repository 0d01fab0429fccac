"""Shared fixtures: the reference data lives in ``../shared`` beside the checkout."""

from __future__ import annotations

import dataclasses
import gzip
import json
import time
import uuid
from pathlib import Path
from typing import Any

import pytest

from autotune.search.cost import FEATURES, CostModel
from tests.postgres import postgres_server, postgres_url  # noqa: F401  (fixtures: a real PostgreSQL server)

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
REFERENCE = SHARED / "reference"
CROWD = SHARED / "crowd"


def forward_cost_model(seconds: float) -> CostModel:
    """A cost model whose only work term is the greedy forward pass: a rung costs ``seconds`` × weights × iterations."""
    return CostModel(tuple(seconds if name == "forward_work" else 0.0 for name in FEATURES))


def load_json(path: Path) -> dict:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as fh:
        return json.load(fh)


@pytest.fixture(scope="session")
def reference() -> Path:
    if not REFERENCE.is_dir():
        pytest.fail(f"reference data not found at {REFERENCE} (CI keeps ../shared beside the checkout)")
    return REFERENCE


@dataclasses.dataclass(frozen=True)
class SmokeLaunch:
    """One ``autotune launch study_configs/smoke.toml`` run for real in ``cwd`` (its runs/ there)."""

    cwd: Path
    rc: int
    out: str
    err: str
    tag: str
    """``AUTOTUNE_TEST_TAG`` of every process it started."""
    wall: float
    """Seconds from the command's start to its exit."""


@pytest.fixture(scope="session")
def smoke_launch(tmp_path_factory: pytest.TempPathFactory) -> SmokeLaunch:
    """The smoke study, launched once for the tests that read it (each copies what it changes): a launch costs
    ~25 s of the 2-core CI machine's time."""
    from tests.test_search_launch import SMOKE, finish, launch

    cwd, tag = tmp_path_factory.mktemp("smoke-launch"), uuid.uuid4().hex
    t0 = time.perf_counter()
    rc, out, err = finish(launch(cwd, str(SMOKE), tag=tag))
    return SmokeLaunch(cwd, rc, out, err, tag, time.perf_counter() - t0)


class FakePool:
    """The calls of ``WorkerPool`` that ``Driver._launch_next`` makes, recording the tasks (no worker runs)."""

    def __init__(self) -> None:
        self.tasks: list[Any] = []

    def worker_of(self, slot: int) -> str:
        return f"test:{slot}"

    def node_of(self, slot: int) -> str:
        return "node"

    def submit(self, slot: int, task: Any) -> None:
        self.tasks.append(task)
