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

Read-only commands open with ``read_only=True``: nothing is created (no journal, lock file,
database file, table, version row or artifact directory) and nothing can be written — a journal is
read by ``ReadOnlyJournal`` (never locked or appended to), SQLite opens in its read-only mode and
PostgreSQL sessions are read-only transactions. A journal with a bad line before its end, or a
storage that is not Optuna's (a file that is not a journal, a database without Optuna's tables), is
a ``StorageError`` naming the file or URL. A journal's last line without its newline is a writer
mid-append, not damage: the complete lines before it are read.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import os
import re
import time
import urllib.parse
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import optuna
from optuna.artifacts import FileSystemArtifactStore
from optuna.storages import BaseStorage, JournalStorage, RDBStorage
from optuna.storages.journal import BaseJournalBackend, JournalFileBackend, JournalFileSymlinkLock

from sim.config import ConfigError

__all__ = [
    "CONNECT_TIMEOUT_S",
    "GRACE_PERIOD_S",
    "HEARTBEAT_INTERVAL_S",
    "OPTUNA_TABLES",
    "RUNS_DIR",
    "JournalRepairedWarning",
    "ReadOnlyJournal",
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
OPTUNA_TABLES = ("studies", "trials", "version_info")
"""Tables every Optuna RDB storage has; a database without them is not (yet) a study storage."""
_SQLITE_MAGIC = b"SQLite format 3\x00"  # the first bytes of every SQLite database file
_JOURNAL_FIX = "restore it from a copy, or delete that line to read the records around it"


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
    read_only: bool = False
    """Opened for reading only: the storage refuses every write."""


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


def _artifact_store(directory: Path, shown: str, create: bool) -> tuple[FileSystemArtifactStore, Path]:
    """The artifact store in ``directory``, made (and checked writable) only when ``create``."""
    if not create:  # a reader downloads from it if it is there; a missing one is a missing artifact, later
        return FileSystemArtifactStore(str(directory)), directory
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


class ReadOnlyJournal(BaseJournalBackend):
    """An Optuna journal file read as it stands: never created, locked or written to.

    Lines are read up to the last one ending in a newline; a last line without it that starts a JSON
    object is a record a writer is appending at this moment (Optuna writes each batch of records
    with one ``write``), so it is left for the next read. A complete line that is not a JSON object with an integer
    ``op_code`` is damage: ``StorageError`` naming the file and the line — on line 1, the file is not
    an Optuna journal at all.
    """

    def __init__(self, path: Path, shown: str) -> None:
        self.path = path
        self.shown = shown
        """The journal as the user named it (for messages)."""
        self.line = 0
        """The line of the record handed out last (1-based): the one Optuna was applying when it failed."""
        self._offsets = {0: 0}  # record number -> byte offset of its line, for each complete line seen

    def read_logs(self, log_number_from: int) -> Iterator[dict[str, Any]]:
        number = max(n for n in self._offsets if n <= log_number_from)
        try:
            with self.path.open("rb") as f:
                f.seek(self._offsets[number])
                for line in f:
                    if not line.endswith(b"\n"):
                        if line.startswith(b"{"):
                            return  # torn: a writer mid-append (every record is a JSON object)
                        raise self.damage(number + 1, "not JSON: no '{' at column 1, and no newline")
                    record = self._parse(line, number + 1)
                    self._offsets[number + 1] = self._offsets[number] + len(line)
                    number += 1
                    if number > log_number_from:
                        self.line = number
                        yield record
        except OSError as exc:
            raise StorageError(f"storage '{self.shown}': cannot read the journal file ({_reason(exc)})") from None

    def append_logs(self, logs: list[dict[str, Any]]) -> None:
        raise StorageError(f"storage '{self.shown}': opened read-only; this command does not write to a study")

    def _parse(self, line: bytes, number: int) -> dict[str, Any]:
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            why = f"not JSON: {exc.msg.removesuffix(' at')} at column {exc.colno}"
        except ValueError:  # bytes that are not UTF-8
            why = "not UTF-8 text"
        else:
            op = record.get("op_code") if isinstance(record, dict) else None
            if isinstance(op, int) and not isinstance(op, bool):
                return record  # type: ignore[no-any-return]
            why = "JSON but no journal record: no integer op_code"
        raise self.damage(number, why)

    def damage(self, number: int, why: str) -> StorageError:
        """The error for line ``number`` of the file, which is not a record Optuna can read (``why``)."""
        if number <= 1:
            with self.path.open("rb") as f:
                sqlite = f.read(len(_SQLITE_MAGIC)) == _SQLITE_MAGIC
            if sqlite:
                return StorageError(
                    f"storage '{self.shown}': not an Optuna journal file but an SQLite database; "
                    f"pass --storage sqlite:///{self.path}"
                )
            return StorageError(
                f"storage '{self.shown}': not an Optuna journal file (line 1: {why}); pass the study's journal file"
            )
        return StorageError(
            f"storage '{self.shown}': damaged journal: line {number} is not a journal record ({why}); {_JOURNAL_FIX}"
        )


def _read_journal(path: Path, shown: str) -> JournalStorage:
    """The journal at ``path`` (which exists) opened read-only, every record in it applied."""
    backend = ReadOnlyJournal(path, shown)
    try:
        return JournalStorage(backend)  # replays the whole file now: damage shows here
    except StorageError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, AssertionError) as exc:
        raise backend.damage(backend.line, f"a record Optuna cannot apply: {type(exc).__name__} {exc}") from None


class JournalRepairedWarning(UserWarning):
    """A writer opening a journal cut off a torn last record that a dead writer left."""


def _line_start(f: Any, pos: int) -> int:
    """Offset of the first byte after the last newline before ``pos`` (0 if none), read backwards in chunks."""
    chunk = 1 << 16
    while pos > 0:
        lo = max(0, pos - chunk)
        f.seek(lo)
        i = f.read(pos - lo).rfind(b"\n")
        if i >= 0:
            return lo + i + 1
        pos = lo
    return 0


def _settle_tail(path: Path, shown: str, lock: JournalFileSymlinkLock) -> None:
    """Before a writer appends: cut a torn last record off, and refuse a complete last line that is damage.

    Optuna's reader skips a last line that is torn (no newline) or not JSON, so a writer would append after
    it and turn it into a middle line that no reader can apply: every finished trial behind it would be
    unreadable. Appends hold the journal's lock, so a torn line found while holding it is what a writer that
    died mid-append (a killed driver) left: it was never a record (readers skip it), and it is cut off with
    a ``JournalRepairedWarning``. A complete last line that is not a record is damage (``StorageError``).
    """
    if path.stat().st_size == 0:
        return
    lock.acquire()
    try:
        with path.open("rb+") as f:
            size = f.seek(0, os.SEEK_END)
            f.seek(size - 1)
            if f.read(1) != b"\n":
                start = _line_start(f, size)
                f.truncate(start)
                f.flush()
                os.fsync(f.fileno())
                warnings.warn(JournalRepairedWarning(
                    f"storage '{shown}': cut off a torn last record ({size - start:,} bytes without a newline) "
                    "that a writer which died mid-append left; every complete record is kept"
                ), stacklevel=3)  # fmt: skip
                size = start
            if size == 0:
                return
            f.seek(_line_start(f, size - 1))
            line = f.read(size - f.tell())
            backend = ReadOnlyJournal(path, shown)
            try:
                backend._parse(line, 0)  # noqa: SLF001 - its own class's check of one line
            except StorageError:
                f.seek(0)
                number = sum(block.count(b"\n") for block in iter(lambda: f.read(1 << 20), b""))
                backend._parse(line, number)  # noqa: SLF001 - raises again, naming the line
    finally:
        lock.release()


LOCK_GRACE_S = 30  # Optuna's JournalFileSymlinkLock default: a lock held this long unchanged is a dead writer's


def _release_dangling_lock(lock: Path, shown: str) -> None:
    """Remove a journal lock whose symlink points nowhere once it is ``LOCK_GRACE_S`` old.

    Optuna's lock is a symlink to the journal, and its grace period reads the age through the link
    (``os.stat``). A lock taken through a relative journal path points nowhere (the target is resolved
    beside the link), so when a writer is killed holding it, every later writer waits on it for ever: a
    resumed driver hung so. Writers here take it through the absolute path; this clears one that an
    older writer left, after the same grace period, judged by the link's own time.
    """
    while lock.is_symlink() and not lock.exists():
        try:
            age = time.time() - lock.lstat().st_mtime
        except FileNotFoundError:  # released meanwhile
            return
        if age < LOCK_GRACE_S:
            time.sleep(min(LOCK_GRACE_S - age, 0.5))
            continue
        lock.unlink(missing_ok=True)
        warnings.warn(JournalRepairedWarning(
            f"storage '{shown}': removed the journal lock {lock.name} that a writer killed while holding it "
            f"left {age:.0f} s ago"
        ), stacklevel=4)  # fmt: skip
        return


def _open_journal(path: Path, shown: str) -> JournalStorage:
    try:
        path = path.absolute()  # the lock's symlink names this path: absolute, it resolves (see above)
        path.parent.mkdir(parents=True, exist_ok=True)
        _release_dangling_lock(Path(str(path) + ".lock"), shown)
        lock = JournalFileSymlinkLock(str(path), grace_period=LOCK_GRACE_S)
        backend = JournalFileBackend(str(path), lock_obj=lock)
        if not os.access(path, os.R_OK | os.W_OK) or not os.access(path.parent, os.W_OK | os.X_OK):
            raise PermissionError(f"not writable: {path}")  # the lock file is created beside the journal
        _settle_tail(path, shown, lock)
    except OSError as exc:
        raise StorageError(
            f"storage '{shown}': cannot open the journal file ({_reason(exc)}); "
            "pass --storage PATH.log in a writable directory, or an SQLAlchemy URL"
        ) from None
    try:
        return JournalStorage(backend)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, AssertionError) as exc:
        _read_journal(path, shown)  # names the damaged line
        raise StorageError(f"storage '{shown}': cannot read the journal ({_reason(exc)}); {_JOURNAL_FIX}") from None


def _journal(path: Path, shown: str, study_name: str, create: bool, read_only: bool) -> JournalStorage:
    if not create and not path.is_file():
        if path.exists():
            raise StorageError(
                f"storage '{shown}': not a journal file (a directory or a device); pass the study's journal"
            )
        raise UnknownStudyError(
            f"storage '{shown}': no study '{study_name}' (the journal file does not exist); "
            "launch the study first, or pass --storage"
        )
    return _read_journal(path, shown) if read_only else _open_journal(path, shown)


def _open_rdb(
    url: str, shown: str, heartbeat: bool, study_name: str, create: bool, read_only: bool
) -> tuple[RDBStorage, str]:
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
    if dialect == "postgresql" and read_only:
        connect_args["options"] = "-c default_transaction_read_only=on"  # the server refuses every write
    database = parsed.database or ""
    if dialect == "sqlite" and database not in ("", ":memory:") and not database.startswith("file:"):
        file = Path(database)
        if not create and not file.is_file():
            raise UnknownStudyError(
                f"storage '{shown}': no study '{study_name}' (the SQLite file {file} does not exist); "
                "launch the study first, or pass --storage"
            )
        if read_only:  # SQLite's read-only mode: never creates the file, refuses every write
            path = urllib.parse.quote(str(file.resolve()))
            parsed = parsed.set(database=f"file:{path}", query={**parsed.query, "mode": "ro", "uri": "true"})
        elif not file.parent.is_dir():
            raise StorageError(
                f"storage '{shown}': the directory {file.parent} of the SQLite file does not exist; create it first"
            )
    engine_kwargs: dict[str, Any] = {"pool_pre_ping": True}
    if connect_args:
        engine_kwargs["connect_args"] = connect_args
    beat: dict[str, Any] = {}
    if heartbeat:
        beat = {"heartbeat_interval": HEARTBEAT_INTERVAL_S, "grace_period": GRACE_PERIOD_S}
    full = parsed.render_as_string(hide_password=False)
    try:
        if not create:
            _require_optuna_tables(full, engine_kwargs, shown, dialect, study_name)
        storage = _create_rdb(full, engine_kwargs, beat, skip_table_creation=not create)
    except StorageError:
        raise
    except NoSuchModuleError:
        raise StorageError(
            f"storage '{shown}': SQLAlchemy has no database driver '{parsed.drivername}'; "
            "use sqlite:///PATH.db or postgresql://user:password@host:5432/db"
        ) from None
    except RuntimeError as exc:  # Optuna: the tables' schema is another Optuna version's
        raise StorageError(f"storage '{shown}': {_reason(exc)}") from None
    except (SQLAlchemyError, ImportError, OSError, ValueError) as exc:
        fix = {
            "sqlite": "check the file path and that its directory is writable",
            "postgresql": "check host, port, user, password and database, and that the server is running",
        }.get(dialect, "check the URL and that the database server is running")
        raise StorageError(f"storage '{shown}': cannot connect ({_reason(_root_cause(exc))}); {fix}") from None
    return storage, dialect


def _require_optuna_tables(url: str, engine_kwargs: dict[str, Any], shown: str, dialect: str, study_name: str) -> None:
    """Fail unless the database at ``url`` holds Optuna's tables — looked at only, nothing created.

    An empty database holds no study (``UnknownStudyError``); one with other tables, or a file that
    is not a database, is not an Optuna storage (``StorageError``).
    """
    import sqlalchemy
    from sqlalchemy.exc import DatabaseError

    engine = sqlalchemy.create_engine(url, **engine_kwargs)
    try:
        with engine.connect() as connection:
            tables = set(sqlalchemy.inspect(connection).get_table_names())
    except DatabaseError as exc:
        cause = _reason(_root_cause(exc))
        if dialect == "sqlite" and "not a database" in cause:
            raise StorageError(
                f"storage '{shown}': not an Optuna storage ({cause}); pass the study's storage"
            ) from None
        raise
    finally:
        engine.dispose()
    missing = [t for t in OPTUNA_TABLES if t not in tables]
    if not missing:
        return
    if not tables:
        raise UnknownStudyError(
            f"storage '{shown}': no study '{study_name}' (the database has no tables: no study was created there); "
            "launch the study first, or check the URL"
        )
    found = ", ".join(sorted(tables)[:5]) + (", …" if len(tables) > 5 else "")
    raise StorageError(
        f"storage '{shown}': not an Optuna storage (tables {found}; no {', '.join(missing)}); check the URL"
    )


def _create_rdb(
    url: str, engine_kwargs: dict[str, Any], beat: dict[str, Any], *, skip_table_creation: bool = False
) -> RDBStorage:
    """``RDBStorage(url)``, retried when another process creates Optuna's tables at the same moment.

    Two drivers started together on an empty database both run ``CREATE TABLE``; the loser gets a
    duplicate-object error (PostgreSQL: unique violation on pg_type). The tables exist by then, so a
    second attempt just finds them. ``skip_table_creation``: the tables exist already (checked).
    """
    from sqlalchemy.exc import IntegrityError, ProgrammingError

    for attempt in range(_CREATE_ATTEMPTS):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)  # heartbeat_interval
                return RDBStorage(url, engine_kwargs=engine_kwargs, skip_table_creation=skip_table_creation, **beat)
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
    read_only: bool = False,
) -> Storages:
    """Open the study storage named by ``storage`` (``--storage``) and its artifact store.

    ``study_name`` places the embedded journal and the default artifact store in
    ``runs/<study>/``; ``artifacts`` overrides the artifact directory. ``heartbeat`` (RDB storages):
    trials record heartbeats every ``HEARTBEAT_INTERVAL_S`` and count as failed after
    ``GRACE_PERIOD_S`` of silence — read-only commands pass False. Raises ``StorageError`` (one
    line) for a storage that cannot be opened, is damaged or is not Optuna's; an RDB server is
    contacted here, so an unreachable one fails now, within ``CONNECT_TIMEOUT_S``.

    ``create=False``: open what exists and create nothing — a journal file, SQLite file or database
    without Optuna's tables that is not there is an ``UnknownStudyError``, the artifact directory is
    not made — but allow writes (``compare`` attaching figures to a study). ``read_only=True``
    (``status``, ``best``, ``compare``, ``replay``, ``dashboard``, ``evaluate --trial``): as
    ``create=False``, and the storage refuses every write.
    """
    storage = storage.strip()
    shown = display_url(storage)
    art_dir = Path(artifacts) if artifacts else None
    create = create and not read_only
    heartbeat = heartbeat and not read_only  # a reader runs no trial
    if not storage:
        run_dir = _study_dir(study_name, "the embedded storage")
        journal = run_dir / "journal.log"
        opened: BaseStorage = _journal(journal, str(journal), study_name, create, read_only)
        store, art_dir = _artifact_store(art_dir or run_dir / "artifacts", str(journal), create)
        return Storages(opened, store, art_dir, str(journal), "journal", read_only)
    if "://" in storage:
        opened, dialect = _open_rdb(storage, shown, heartbeat, study_name, create, read_only)
        art_dir = art_dir or _study_dir(study_name, "its artifact store") / "artifacts"
        store, art_dir = _artifact_store(art_dir, shown, create)
        return Storages(opened, store, art_dir, shown, dialect, read_only)
    path = Path(storage).expanduser()
    if path.suffix not in JOURNAL_SUFFIXES:
        raise StorageError(
            f"storage '{storage}': expected a journal file (*.log or *.journal) or an SQLAlchemy URL "
            "(sqlite:///study.db, postgresql://user@host/db); leave it empty for runs/<study>/journal.log"
        )
    opened = _journal(path, storage, study_name, create, read_only)
    store, art_dir = _artifact_store(art_dir or path.parent / "artifacts", storage, create)
    return Storages(opened, store, art_dir, storage, "journal", read_only)


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
