"""Shared fixtures: the reference data lives in ``../shared`` beside the checkout."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

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
