"""Where a study lives: an Optuna storage plus the artifact store for its trained networks.

``open_storage(storage, study)`` turns the ``--storage`` argument into both, and fails fast — one
line naming the storage (password masked) and the fix, before any worker starts — when it cannot
be used:

* ``""`` — embedded: an Optuna journal file ``runs/<study>/journal.log`` (no server; several
  processes may append to it, serialised by the journal backend's lock file), artifacts in
  ``runs/<study>/artifacts``;
* a path ending in ``.log`` / ``.journal`` — a journal file there, artifacts in a sibling
  ``artifacts/``;
* an SQLAlchemy URL (``sqlite:///study.db``, ``postgresql://user:pw@host/db``, …) — Optuna's
  ``RDBStorage`` with heartbeats on (a driver that dies leaves no trial RUNNING for ever),
  ``pool_pre_ping`` and a short connect timeout; ``postgresql://`` uses the installed psycopg 3
  driver. Artifacts go to ``runs/<study>/artifacts`` unless ``artifacts=`` names a directory
  (drivers on several machines need one shared directory for them).
"""

from __future__ import annotations

import dataclasses
import difflib
import os
import re
import time
import warnings
from pathlib import Path
from typing import Any

import optuna
from optuna.artifacts import FileSystemArtifactStore
from optuna.storages import BaseStorage, JournalStorage, RDBStorage
from optuna.storages.journal import JournalFileBackend, JournalFileSymlinkLock

from sim.config import ConfigError

__all__ = [
    "CONNECT_TIMEOUT_S",
    "GRACE_PERIOD_S",
    "HEARTBEAT_INTERVAL_S",
    "RUNS_DIR",
    "StorageError",
    "Storages",
    "UnknownStudyError",
    "display_url",
    "load_study",
    "open_storage",
    "study_names",
]

RUNS_DIR = Path("runs")  # embedded studies and default artifact stores live in RUNS_DIR/<study>/
JOURNAL_SUFFIXES = (".log", ".journal")
HEARTBEAT_INTERVAL_S = 20  # a RUNNING trial's owner writes a heartbeat this often …
GRACE_PERIOD_S = 90  # … and a trial silent for this long is failed as stale by the next driver
CONNECT_TIMEOUT_S = 5  # a server that does not answer fails the command in seconds, not minutes
_CREATE_ATTEMPTS = 4  # RDBStorage creation tries when drivers race to create the tables
_STUDY_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
_DRIVERS = {"postgresql": "postgresql+psycopg", "postgres": "postgresql+psycopg"}  # bare scheme -> installed driver


class StorageError(ConfigError):
    """A storage that cannot be opened or used; the message names the storage (no password) and the fix."""


class UnknownStudyError(StorageError):
    """The storage holds no study of that name; the message lists the ones it has (nearest first)."""


@dataclasses.dataclass(frozen=True)
class Storages:
    """An opened study storage: Optuna's storage, the artifact store beside it, and how to name it."""

    storage: BaseStorage
    """The Optuna storage (``JournalStorage`` or ``RDBStorage``)."""
    artifacts: FileSystemArtifactStore
    """Where trial artifacts (``net.json``, ``net.js``) are uploaded and downloaded."""
    artifact_dir: Path
    """The artifact store's directory (optuna-dashboard's ``--artifact-dir``)."""
    url: str
    """The storage as a user may see it: the journal path, or the URL with the password masked."""
    kind: str
    """``"journal"``, or the SQLAlchemy dialect of an RDB storage (``"sqlite"``, ``"postgresql"``, …)."""


def display_url(storage: str) -> str:
    """``storage`` safe to print: an SQLAlchemy URL's password replaced by ``***``."""
    if "://" not in storage:
        return storage
    try:
        from sqlalchemy.engine import make_url

        return make_url(storage).render_as_string(hide_password=True)
    except Exception:  # a malformed URL: mask whatever sits between 'user:' and '@'
        return re.sub(r"(://[^:/@]*:)[^@]*@", r"\1***@", storage)


def _study_dir(study_name: str, what: str) -> Path:
    if not _STUDY_NAME.fullmatch(study_name):
        raise StorageError(
            f"study name '{study_name}': {what} is runs/<study>/, so the name must be letters, digits, '.', '_' "
            "or '-' (start with a letter or digit); rename the study or pass an explicit path"
        )
    return RUNS_DIR / study_name


def _artifact_store(directory: Path, shown: str) -> tuple[FileSystemArtifactStore, Path]:
    try:
        directory.mkdir(parents=True, exist_ok=True)
        if not os.access(directory, os.W_OK | os.X_OK):
            raise PermissionError(f"directory not writable: {directory}")
    except OSError as exc:
        raise StorageError(
            f"storage '{shown}': cannot create the artifact directory {directory} ({_reason(exc)}); "
            "pass a writable --artifacts DIR"
        ) from None
    return FileSystemArtifactStore(str(directory)), directory


def _reason(exc: BaseException) -> str:
    if isinstance(exc, FileExistsError) and exc.filename and not Path(exc.filename).is_dir():
        return f"{exc.filename} is not a directory"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _open_journal(path: Path, shown: str) -> JournalStorage:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        backend = JournalFileBackend(str(path), lock_obj=JournalFileSymlinkLock(str(path)))
        if not os.access(path, os.R_OK | os.W_OK) or not os.access(path.parent, os.W_OK | os.X_OK):
            raise PermissionError(f"not writable: {path}")  # the lock file is created beside the journal
        return JournalStorage(backend)
    except OSError as exc:
        raise StorageError(
            f"storage '{shown}': cannot open the journal file ({_reason(exc)}); "
            "pass --storage PATH.log in a writable directory, or an SQLAlchemy URL"
        ) from None


def _open_rdb(url: str, shown: str, heartbeat: bool) -> tuple[RDBStorage, str]:
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError, NoSuchModuleError, SQLAlchemyError

    try:
        parsed = make_url(url)
    except (ArgumentError, ValueError) as exc:
        raise StorageError(
            f"storage '{shown}': not an SQLAlchemy URL ({_reason(exc)}); "
            "use e.g. sqlite:///study.db or postgresql://user:password@host:5432/db"
        ) from None
    if parsed.drivername in _DRIVERS:
        parsed = parsed.set(drivername=_DRIVERS[parsed.drivername])
    dialect = parsed.get_backend_name()
    connect_args: dict[str, Any] = {}
    if dialect in ("postgresql", "mysql"):
        connect_args["connect_timeout"] = CONNECT_TIMEOUT_S
    if dialect == "sqlite" and parsed.database not in (None, "", ":memory:"):
        parent = Path(parsed.database).parent
        if not parent.is_dir():
            raise StorageError(
                f"storage '{shown}': the directory {parent} of the SQLite file does not exist; create it first"
            )
    engine_kwargs: dict[str, Any] = {"pool_pre_ping": True}
    if connect_args:
        engine_kwargs["connect_args"] = connect_args
    beat: dict[str, Any] = {}
    if heartbeat:
        beat = {"heartbeat_interval": HEARTBEAT_INTERVAL_S, "grace_period": GRACE_PERIOD_S}
    try:
        storage = _create_rdb(parsed.render_as_string(hide_password=False), engine_kwargs, beat)
    except NoSuchModuleError:
        raise StorageError(
            f"storage '{shown}': SQLAlchemy has no database driver '{parsed.drivername}'; "
            "use sqlite:///PATH.db or postgresql://user:password@host:5432/db"
        ) from None
    except (SQLAlchemyError, ImportError, OSError, RuntimeError, ValueError) as exc:
        fix = {
            "sqlite": "check the file path and that its directory is writable",
            "postgresql": "check host, port, user, password and database, and that the server is running",
        }.get(dialect, "check the URL and that the database server is running")
        raise StorageError(f"storage '{shown}': cannot connect ({_reason(_root_cause(exc))}); {fix}") from None
    return storage, dialect


def _create_rdb(url: str, engine_kwargs: dict[str, Any], beat: dict[str, Any]) -> RDBStorage:
    """``RDBStorage(url)``, retried when another process creates Optuna's tables at the same moment.

    Two drivers started together on an empty database both run ``CREATE TABLE``; the loser gets a
    duplicate-object error (PostgreSQL: unique violation on pg_type). The tables exist by then, so a
    second attempt just finds them.
    """
    from sqlalchemy.exc import IntegrityError, ProgrammingError

    for attempt in range(_CREATE_ATTEMPTS):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)  # heartbeat_interval
                return RDBStorage(url, engine_kwargs=engine_kwargs, **beat)
        except (IntegrityError, ProgrammingError) as exc:
            text = str(exc).lower()
            if attempt + 1 == _CREATE_ATTEMPTS or ("already exists" not in text and "duplicate" not in text):
                raise
            time.sleep(0.2 * (attempt + 1))
    raise AssertionError("unreachable")


def _root_cause(exc: BaseException) -> BaseException:
    orig = getattr(exc, "orig", None)  # sqlalchemy wraps the driver's error
    return orig if isinstance(orig, BaseException) else exc


def open_storage(
    storage: str,
    study_name: str,
    *,
    heartbeat: bool = True,
    artifacts: str | Path | None = None,
    create: bool = True,
) -> Storages:
    """Open the study storage named by ``storage`` (``--storage``) and its artifact store.

    ``study_name`` places the embedded journal and the default artifact store in
    ``runs/<study>/``; ``artifacts`` overrides the artifact directory. ``heartbeat`` (RDB storages):
    trials record heartbeats every ``HEARTBEAT_INTERVAL_S`` and count as failed after
    ``GRACE_PERIOD_S`` of silence — read-only commands pass False. Raises ``StorageError`` (one
    line) for a storage that cannot be opened; an RDB server is contacted here, so an unreachable
    one fails now, within ``CONNECT_TIMEOUT_S``. ``create=False`` (read-only commands): a journal
    file that does not exist is an ``UnknownStudyError`` instead of a new, empty ``runs/<study>/``.
    """
    storage = storage.strip()
    shown = display_url(storage)
    art_dir = Path(artifacts) if artifacts else None
    if not storage:
        run_dir = _study_dir(study_name, "the embedded storage")
        journal = run_dir / "journal.log"
        _require_journal(journal, study_name, create)
        opened: BaseStorage = _open_journal(journal, str(journal))
        store, art_dir = _artifact_store(art_dir or run_dir / "artifacts", str(journal))
        return Storages(opened, store, art_dir, str(journal), "journal")
    if "://" in storage:
        opened, dialect = _open_rdb(storage, shown, heartbeat)
        store, art_dir = _artifact_store(art_dir or _study_dir(study_name, "its artifact store") / "artifacts", shown)
        return Storages(opened, store, art_dir, shown, dialect)
    path = Path(storage).expanduser()
    if path.suffix not in JOURNAL_SUFFIXES:
        raise StorageError(
            f"storage '{storage}': expected a journal file (*.log or *.journal) or an SQLAlchemy URL "
            "(sqlite:///study.db, postgresql://user@host/db); leave it empty for runs/<study>/journal.log"
        )
    _require_journal(path, study_name, create)
    opened = _open_journal(path, storage)
    store, art_dir = _artifact_store(art_dir or path.parent / "artifacts", storage)
    return Storages(opened, store, art_dir, storage, "journal")


def _require_journal(path: Path, study_name: str, create: bool) -> None:
    if not create and not path.is_file():
        raise UnknownStudyError(
            f"storage '{path}': no study '{study_name}' (the journal file does not exist); "
            "launch the study first, or pass --storage"
        )


def study_names(storages: Storages) -> list[str]:
    """The names of the studies in the storage, in creation order."""
    return [s.study_name for s in storages.storage.get_all_studies()]


def load_study(storages: Storages, study_name: str) -> optuna.Study:
    """The existing study ``study_name``; ``UnknownStudyError`` (one line, nearest names first) otherwise."""
    names = study_names(storages)
    if study_name not in names:
        near = difflib.get_close_matches(study_name, names, n=len(names), cutoff=0.0) if names else []
        hint = f"; did you mean '{near[0]}'?" if near else ""
        listed = ", ".join(near) if near else "none"
        raise UnknownStudyError(f"storage '{storages.url}': no study '{study_name}'{hint} (studies there: {listed})")
    return optuna.load_study(study_name=study_name, storage=storages.storage)
