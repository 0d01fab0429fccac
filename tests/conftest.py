"""Shared fixtures: the reference data lives in ``../shared`` beside the checkout."""

from __future__ import annotations

import gzip
import json
from pathlib import Path
from typing import Any

import pytest

from tests.postgres import postgres_server, postgres_url  # noqa: F401  (fixtures: a real PostgreSQL server)

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
REFERENCE = SHARED / "reference"
CROWD = SHARED / "crowd"


def load_json(path: Path) -> dict:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as fh:
        return json.load(fh)


@pytest.fixture(scope="session")
def reference() -> Path:
    if not REFERENCE.is_dir():
        pytest.fail(f"reference data not found at {REFERENCE} (CI keeps ../shared beside the checkout)")
    return REFERENCE


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
