"""Read-only means read-only, and every failure is one line (issue 15 §5).

``status``, ``best``, ``compare``, ``replay``, ``dashboard`` and ``evaluate --trial`` read a study:
on a damaged journal, a foreign storage (a file that is not a journal, an SQLite or PostgreSQL
database without Optuna's tables) or a missing one they print one line naming the file or URL and
exit 2, and — failing or not — they leave the storage as it was and create nothing (no journal,
lock file, database file, table, study or artifact directory; asserted on the file system and the
database after each call). A journal's torn last line (a writer mid-append) is not damage. Output
destinations are checked before any work; a study without a finished trial has no rates.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import io
import json
import os
import sqlite3
import time
from pathlib import Path
from typing import Any
from wsgiref.util import setup_testing_defaults

import optuna
import pytest
from optuna.trial import TrialState, create_trial

from autotune import cli
from autotune.cliutil import output_dir, output_file
from autotune.search.dashboard import DashboardServer
from autotune.search.records import read_study
from autotune.search.storage import StorageError, open_storage, study_names
from sim.config import ConfigError
from tests.test_search_inspect import make_study

STUDY = "demo"
READERS: dict[str, list[str]] = {
    "status": ["status", STUDY],
    "best": ["best", STUDY, "--json"],
    "best --export": ["best", STUDY, "--export", "exported"],
    "compare": ["compare", STUDY, "--out", "report.html", "--no-spread"],
    "replay": ["replay", STUDY, "--out", "run.html", "--frames", "6", "--every", "3", "--run-frames", "30"],
    "dashboard": ["dashboard", STUDY, "--port", "0"],
    "evaluate --trial": ["evaluate", "--trial", f"{STUDY}:1"],
}
"""Every command that reads a study, as run against ``--storage``."""


@pytest.fixture(autouse=True)
def _no_serving(monkeypatch: pytest.MonkeyPatch) -> None:
    """A dashboard that gets as far as serving stops at once (so a test never hangs on one)."""
    monkeypatch.setattr(DashboardServer, "serve_forever", DashboardServer.close)


@pytest.fixture(autouse=True)
def _quiet_optuna() -> None:
    optuna.logging.set_verbosity(optuna.logging.WARNING)


def tree(root: Path) -> dict[str, str]:
    """Every path under ``root``: 'dir', or a file's content digest and mtime — what a reader must leave alone."""
    out = {}
    for path in sorted(root.rglob("*")):
        if path.is_dir():
            out[str(path.relative_to(root))] = "dir"
        else:
            digest = hashlib.sha1(path.read_bytes()).hexdigest()
            out[str(path.relative_to(root))] = f"{digest} {path.stat().st_mtime_ns}"
    return out


def refused(exc: BaseException) -> bool:
    """Whether ``exc`` or an error it was raised from says the storage is read-only."""
    chain: BaseException | None = exc
    while chain is not None:
        if any(word in str(chain).lower() for word in ("read-only", "readonly")):
            return True
        chain = chain.__cause__ or chain.__context__
    return False


def one_line(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """Run ``autotune ARGV``; assert it failed as bad input (exit 2, one line on stderr, nothing on stdout)."""
    code = cli.main(argv, owns_process=False)
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and err.startswith("error: ") and err.count("\n") == 1, (argv, code, out, err)
    return err.strip()


@pytest.fixture(scope="module")
def journal_lines(tmp_path_factory: pytest.TempPathFactory) -> list[bytes]:
    """The lines of a finished study's journal (``make_study``: 2 complete trials with nets, 1 pruned, 1 failed)."""
    root = tmp_path_factory.mktemp("source")
    make_study(open_storage(str(root / "journal.log"), STUDY), STUDY)
    return (root / "journal.log").read_bytes().splitlines(keepends=True)


def _sqlite(path: Path, sql: str = "CREATE TABLE t (x INTEGER)") -> None:
    with sqlite3.connect(path) as db:
        db.execute(sql)
    db.close()


def _storage_case(name: str, root: Path, lines: list[bytes]) -> tuple[str, str]:
    """Make the storage of case ``name`` in ``root``: (--storage, the text its one line must hold)."""
    bad = b'{"op_code": 4, "worker_id": "w", "tri\n'
    if name == "bad line in the middle":
        (root / "bad.log").write_bytes(b"".join([*lines[:5], bad, *lines[5:]]))
        return "bad.log", "storage 'bad.log': damaged journal: line 6 is not a journal record (not JSON"
    if name == "bad last complete line":
        (root / "bad.log").write_bytes(b"".join([*lines, b"garbage\n"]))
        return "bad.log", f"storage 'bad.log': damaged journal: line {len(lines) + 1} is not a journal record"
    if name == "record Optuna cannot apply":
        (root / "bad.log").write_bytes(b"".join([*lines[:3], b'{"op_code": 6, "worker_id": "w"}\n', *lines[3:]]))
        return "bad.log", "storage 'bad.log': damaged journal: line 4 is not a journal record (a record Optuna cannot"
    if name == "NUL bytes after the last record":
        (root / "bad.log").write_bytes(b"".join([*lines, b"\0" * 64]))
        return "bad.log", f"storage 'bad.log': damaged journal: line {len(lines) + 1} is not a journal record"
    if name == "text file":
        (root / "notes.log").write_text("hello\nworld\n")
        return "notes.log", "storage 'notes.log': not an Optuna journal file (line 1: not JSON"
    if name == "JSON lines, not a journal":
        (root / "events.log").write_text('{"event": "start"}\n{"event": "stop"}\n')
        return "events.log", "storage 'events.log': not an Optuna journal file (line 1: JSON but no journal record"
    if name == "SQLite file as a journal":
        _sqlite(root / "study.log")
        return "study.log", "storage 'study.log': not an Optuna journal file but an SQLite database"
    if name == "directory as a journal":
        (root / "dir.log").mkdir()
        return "dir.log", "storage 'dir.log': not a journal file"
    if name == "missing journal":
        return "missing.log", f"storage 'missing.log': no study '{STUDY}' (the journal file does not exist)"
    if name == "SQLite without Optuna's tables":
        _sqlite(root / "other.db")
        return "sqlite:///other.db", "storage 'sqlite:///other.db': not an Optuna storage (tables t; no studies"
    if name == "text file as SQLite":
        (root / "text.db").write_text("hello\n")
        return "sqlite:///text.db", "storage 'sqlite:///text.db': not an Optuna storage (file is not a database)"
    if name == "empty SQLite file":
        (root / "empty.db").touch()
        return "sqlite:///empty.db", f"storage 'sqlite:///empty.db': no study '{STUDY}' (the database has no tables"
    if name == "missing SQLite file":
        return "sqlite:///missing.db", f"no study '{STUDY}' (the SQLite file missing.db does not exist)"
    raise AssertionError(name)


STORAGE_CASES = (
    "bad line in the middle", "bad last complete line", "record Optuna cannot apply", "NUL bytes after the last record",
    "text file", "JSON lines, not a journal", "SQLite file as a journal", "directory as a journal", "missing journal",
    "SQLite without Optuna's tables", "text file as SQLite", "empty SQLite file", "missing SQLite file",
)  # fmt: skip


@pytest.mark.parametrize("case", STORAGE_CASES)
def test_bad_storage_is_one_line_from_every_reader_and_nothing_is_created(
    case: str, journal_lines: list[bytes], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    monkeypatch.chdir(tmp_path)
    storage, expect = _storage_case(case, tmp_path, journal_lines)
    before = tree(tmp_path)
    for name, argv in READERS.items():
        err = one_line(capsys, [*argv, "--storage", storage])
        assert expect in err, (name, err)
        assert tree(tmp_path) == before, name  # no runs/, lock file, database file, export, report, replay


def test_a_damaged_journal_is_one_line_for_a_writer_too(journal_lines: list[bytes], tmp_path: Path) -> None:
    """``launch`` and ``crowd`` open journals for writing: the same line, not a JSONDecodeError traceback."""
    storage, expect = _storage_case("bad line in the middle", tmp_path, journal_lines)
    with pytest.raises(StorageError, match="damaged journal: line 6 is not a journal record"):
        open_storage(str(tmp_path / storage), STUDY)


def test_a_torn_last_line_is_a_writer_mid_append_not_damage(
    journal_lines: list[bytes], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "full.log").write_bytes(b"".join(journal_lines))
    last = journal_lines[-1]
    (tmp_path / "live.log").write_bytes(b"".join(journal_lines[:-1]) + last[: len(last) // 2])
    full = read_study(open_storage("full.log", STUDY, read_only=True), STUDY)
    live_storages = open_storage("live.log", STUDY, read_only=True)
    before = read_study(live_storages, STUDY)
    assert before.trials == full.trials[:-1]  # all but the last record (make_study adds a trial per record)
    with (tmp_path / "live.log").open("ab") as f:  # the writer finishes its line
        f.write(last[len(last) // 2 :])
    assert read_study(live_storages, STUDY) == full  # the same reader picks it up
    # through the commands: a torn line is read up to
    with (tmp_path / "live.log").open("ab") as f:
        f.write(b'{"op_code": 8, "worker_id": "w", "trial_id": 0, "user_attr": {"x"')
    snapshot = tree(tmp_path)
    for argv in (["status", STUDY, "--json"], ["best", STUDY, "--json"]):
        assert cli.main([*argv, "--storage", "full.log"], owns_process=False) == 0
        want = capsys.readouterr().out.replace("full.log", "live.log")
        assert cli.main([*argv, "--storage", "live.log"], owns_process=False) == 0
        assert capsys.readouterr().out == want
    assert tree(tmp_path) == snapshot


def test_reading_a_journal_study_creates_and_changes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    """The embedded storage: every reader succeeds and leaves runs/ as it was (no lock file, no artifact directory)."""
    monkeypatch.chdir(tmp_path)
    make_study(open_storage("", STUDY), STUDY)
    Path("runs/demo/artifacts").rename("store")  # the nets kept elsewhere: status must not make the default folder
    before = tree(tmp_path)
    for name, argv in READERS.items():
        if name in ("compare", "evaluate --trial"):
            continue  # compare: the SQLite test; evaluate --trial re-scores a net (exit 1: the score differs)
        store = ["--artifacts", "store"] if name.startswith(("best", "replay")) else []
        code = cli.main([*argv, *store], owns_process=False)
        out, err = capsys.readouterr()
        assert code == 0 and err == "", (name, err)
    after = tree(tmp_path)
    made = {k for k in after if k not in before}
    assert made == {"exported", "exported/net.json", "exported/net.config.json", "exported/net.js", "run.html"}
    assert {k: v for k, v in after.items() if k in before} == before
    assert cli.main(["status", "typo"], owns_process=False) == 2 and not Path("runs/typo").exists()


def test_a_read_only_storage_refuses_writes(tmp_path: Path) -> None:
    journal = tmp_path / "j.log"
    sqlite_url = f"sqlite:///{tmp_path / 'j.db'}"
    for storage in (str(journal), sqlite_url):
        make_study(open_storage(storage, STUDY, artifacts=tmp_path / "store"), STUDY)
        reader = open_storage(storage, STUDY, read_only=True)
        assert reader.read_only and study_names(reader) == [STUDY]
        with pytest.raises(Exception) as info:
            optuna.create_study(study_name="new", storage=reader.storage)
        assert refused(info.value), repr(info.value)
        assert study_names(open_storage(storage, STUDY, read_only=True)) == [STUDY]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["j.db", "j.log", "store"]  # no lock file left


def _request(app: Any, method: str, path: str, body: bytes = b"") -> tuple[str, bytes]:
    """One WSGI request to ``app``: (status line, body)."""
    environ: dict[str, Any] = {"REQUEST_METHOD": method, "PATH_INFO": path, "CONTENT_LENGTH": str(len(body))}
    setup_testing_defaults(environ)
    environ["wsgi.input"] = io.BytesIO(body)
    got: list[str] = []
    chunks = app(environ, lambda status, headers, exc_info=None: got.append(status))
    return got[0], b"".join(chunks)


def test_the_dashboard_page_cannot_change_the_storage(journal_lines: list[bytes], tmp_path: Path) -> None:
    """optuna-dashboard creates, renames and deletes studies, notes, tells trials: all refused, reads still served."""
    (tmp_path / "j.log").write_bytes(b"".join(journal_lines))
    before = tree(tmp_path)
    server = DashboardServer(open_storage(str(tmp_path / "j.log"), STUDY, read_only=True), STUDY, 0)
    try:
        status, body = _request(server.app, "GET", "/api/studies")
        assert status.startswith("200") and [s["study_name"] for s in json.loads(body)["study_summaries"]] == [STUDY]
        writes = [
            ("POST", "/api/studies", json.dumps({"study_name": "new", "directions": ["maximize"]}).encode()),
            ("DELETE", "/api/studies/0", b""),
            ("PUT", "/api/studies/0/note", json.dumps({"version": 1, "body": "hi"}).encode()),
            ("POST", "/api/trials/2/tell", json.dumps({"state": "Fail"}).encode()),
        ]
        for method, path, payload in writes:
            status, body = _request(server.app, method, path, payload)
            assert status.startswith("403") and "read-only" in json.loads(body)["reason"], (method, path, body)
    finally:
        server.close()
    assert study_names(open_storage(str(tmp_path / "j.log"), STUDY, read_only=True)) == [STUDY]
    assert tree(tmp_path) == before


def test_compare_reads_read_only_and_attaches_only_to_the_existing_study(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    """SQLite: no runs/<study>/artifacts (seen made by compare before), no table or study made; the figures attach."""
    monkeypatch.chdir(tmp_path)
    url = "sqlite:///studies.db"
    make_study(open_storage(url, STUDY, artifacts=tmp_path / "store"), STUDY)
    db = (tmp_path / "studies.db").read_bytes()
    argv = ["compare", STUDY, "--storage", url, "--out", "out/report.html", "--no-spread"]
    assert cli.main([*argv, "--no-dashboard"], owns_process=False) == 0, capsys.readouterr().err
    assert (tmp_path / "studies.db").read_bytes() == db
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "store", "studies.db"]
    assert cli.main(argv, owns_process=False) == 0
    assert "attached" in capsys.readouterr().out
    storages = open_storage(url, STUDY, read_only=True)
    assert study_names(storages) == [STUDY] and not (tmp_path / "runs").exists()
    attrs = storages.storage.get_study_system_attrs(storages.storage.get_study_id_from_name(STUDY))
    assert any(k.startswith("dashboard:plot_data:") for k in attrs) and "dashboard:note_str:0" in attrs


# --------------------------------------------------------------------------------------------
# PostgreSQL (a real server, tests/postgres.py)
# --------------------------------------------------------------------------------------------


def _pg_state(url: str) -> dict[str, int]:
    """Every table of the database with its row count."""
    import sqlalchemy

    engine = sqlalchemy.create_engine(url.replace("postgresql://", "postgresql+psycopg://"))
    try:
        with engine.connect() as c:
            names = sqlalchemy.inspect(c).get_table_names()
            return {n: int(c.exec_driver_sql(f'SELECT count(*) FROM "{n}"').scalar_one()) for n in names}
    finally:
        engine.dispose()


def test_postgresql_database_without_optuna_tables(
    postgres_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    monkeypatch.chdir(tmp_path)
    for name, argv in READERS.items():  # an empty database: no study, and still no table afterwards
        err = one_line(capsys, [*argv, "--storage", postgres_url])
        assert f"no study '{STUDY}' (the database has no tables" in err, (name, err)
        assert _pg_state(postgres_url) == {} and list(tmp_path.iterdir()) == [], name
    import psycopg

    with psycopg.connect(postgres_url, autocommit=True) as c:
        c.execute("CREATE TABLE inventory (item TEXT)")
    for name, argv in READERS.items():
        err = one_line(capsys, [*argv, "--storage", postgres_url])
        assert "not an Optuna storage (tables inventory; no studies, trials, version_info)" in err, (name, err)
        assert _pg_state(postgres_url) == {"inventory": 0} and list(tmp_path.iterdir()) == [], name


def test_postgresql_reads_write_nothing(
    postgres_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    monkeypatch.chdir(tmp_path)
    make_study(open_storage(postgres_url, STUDY, artifacts=tmp_path / "store"), STUDY)
    before = _pg_state(postgres_url)
    for name, argv in READERS.items():
        if name in ("compare", "evaluate --trial"):
            continue  # compare: its own test; evaluate --trial re-scores a net
        code = cli.main([*argv, "--storage", postgres_url, "--artifacts", "store"], owns_process=False)
        assert code == 0, (name, capsys.readouterr().err)
    assert "not an Optuna storage" not in capsys.readouterr().err
    assert one_line(capsys, ["status", "typo", "--storage", postgres_url]).endswith("(studies there: demo)")
    assert (
        cli.main(["compare", STUDY, "--storage", postgres_url, "--out", "r.html", "--no-spread", "--no-dashboard"]) == 0
    )
    assert _pg_state(postgres_url) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exported", "r.html", "run.html", "store"]  # no runs/
    reader = open_storage(postgres_url, STUDY, read_only=True)  # the server refuses a reader's writes
    with pytest.raises(Exception) as info:
        reader.storage.set_study_user_attr(reader.storage.get_study_id_from_name(STUDY), "x", 1)
    assert refused(info.value), repr(info.value)
    assert _pg_state(postgres_url) == before


# --------------------------------------------------------------------------------------------
# output destinations, checked before any work
# --------------------------------------------------------------------------------------------

OUTPUTS = {  # the command (on a damaged journal or a missing net: the output must fail first) and its option
    "compare --out": (["compare", STUDY, "--storage", "bad.log", "--out"], "--out", "file"),
    "replay --out": (["replay", STUDY, "--storage", "bad.log", "--out"], "--out", "file"),
    "replay --net --out": (["replay", "--net", "missing.json", "--out"], "--out", "file"),
    "best --export": (["best", STUDY, "--storage", "bad.log", "--export"], "--export", "dir"),
}


def _unwritable(root: Path) -> Path:
    """A directory this process cannot create files in (root ignores mode bits: /sys refuses it anyway)."""
    if os.geteuid() != 0:
        locked = root / "locked"
        locked.mkdir(mode=0o555)
        return locked
    if not Path("/sys").is_dir():
        pytest.skip("running as root without /sys: no directory it cannot write")
    return Path("/sys")


@pytest.mark.parametrize("command", OUTPUTS)
@pytest.mark.parametrize("place", ["parent is a file", "deeper under a file", "wrong kind", "unwritable directory"])
def test_output_destination_is_checked_first(
    command: str, place: str, journal_lines: list[bytes], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    monkeypatch.chdir(tmp_path)
    _storage_case("bad line in the middle", tmp_path, journal_lines)
    argv, option, kind = OUTPUTS[command]
    (tmp_path / "afile.html").write_text("x")
    (tmp_path / "adir.html").mkdir()
    if place == "parent is a file":
        target, expect = "afile.html/run.html", f"{option}: cannot write afile.html/run.html: afile.html is a file"
    elif place == "deeper under a file":
        target, expect = "afile.html/a/b/run.html", "afile.html is a file, not a directory"
    elif place == "wrong kind" and kind == "file":
        target, expect = "adir.html", f"{option}: adir.html is a directory; name the file to write"
    elif place == "wrong kind":
        target, expect = "afile.html", f"{option}: afile.html is a file, not a directory"
    else:
        locked = _unwritable(tmp_path)
        target, expect = str(locked / "sub" / "run.html"), f"directory {locked} is not writable"
    before = tree(tmp_path)
    err = one_line(capsys, [*argv, target])
    assert expect in err and option in err, err
    assert tree(tmp_path) == before


def test_output_checks_create_nothing(tmp_path: Path) -> None:
    assert output_file(tmp_path / "a" / "b" / "report.html", "--out") == tmp_path / "a" / "b" / "report.html"
    assert output_dir(tmp_path / "x" / "y", "--export") == tmp_path / "x" / "y"
    existing = tmp_path / "old.html"
    existing.write_text("kept")
    stamp = existing.stat().st_mtime_ns
    output_file(existing, "--out")
    assert existing.read_text() == "kept" and existing.stat().st_mtime_ns == stamp
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.html"]
    with pytest.raises(ConfigError, match="--export: .* is a file, not a directory"):
        output_dir(existing, "--export")


# --------------------------------------------------------------------------------------------
# status of a study without a finished trial: a statement, no rates
# --------------------------------------------------------------------------------------------

T0 = dt.datetime(2025, 3, 1, 12, 0, 0)


def _trial(state: TrialState, seconds: float | None, value: float | None = None) -> optuna.trial.FrozenTrial:
    trial = create_trial(state=state, value=value, user_attrs={"frames_simulated": 1000})
    trial.datetime_start = T0 if state != TrialState.WAITING else None
    end = T0 + dt.timedelta(seconds=seconds) if seconds is not None else None
    trial.datetime_complete = end if state.is_finished() else None
    return trial


@pytest.mark.parametrize(
    ("trials", "statement"),
    [
        ([(TrialState.FAIL, 0.00026)], "throughput: no trial has finished yet (1 failed), so no rates"),
        (
            [(TrialState.RUNNING, None), (TrialState.WAITING, None)],
            "throughput: no trial has finished yet, so no rates",
        ),
        ([(TrialState.COMPLETE, 0.004)], "throughput: the finished trials span 0.0 s, too short for rates"),
    ],
    ids=["only a failure", "running and waiting", "milliseconds"],
)
def test_status_without_a_finished_trial_has_no_rates(
    trials: list[tuple[TrialState, float | None]], statement: str, tmp_path: Path, capsys: Any
) -> None:
    storage = str(tmp_path / "j.log")
    study = optuna.create_study(study_name="s", storage=open_storage(storage, "s").storage, direction="maximize")
    for state, seconds in trials:
        study.add_trial(_trial(state, seconds, 60.0 if state == TrialState.COMPLETE else None))
    assert cli.main(["status", "s", "--storage", storage], owns_process=False) == 0
    out = capsys.readouterr().out
    assert statement in out and "trials/h" not in out and "frames/s" not in out, out
    assert cli.main(["status", "s", "--storage", storage, "--json"], owns_process=False) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["trials_per_hour"] is None and summary["frames_per_second"] is None


def test_compare_reads_a_named_journal_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any) -> None:
    """The study, the crowd study and the replay study share the ``--storage`` journal: it is replayed once
    (each replay of a 5,000-trial journal reads ~50–100 MB), and once more only to attach the figures."""
    from autotune.search import storage as storage_module

    monkeypatch.chdir(tmp_path)
    make_study(open_storage(str(tmp_path / "j.log"), STUDY, artifacts=tmp_path / "store"), STUDY)
    reads: list[str] = []
    real = storage_module._read_journal  # noqa: SLF001 - counted, not replaced

    def counted(path: Path, shown: str) -> Any:
        reads.append(str(path))
        return real(path, shown)

    monkeypatch.setattr(storage_module, "_read_journal", counted)
    argv = ["compare", STUDY, "--storage", "j.log", "--out", "report.html", "--no-spread", "--no-dashboard"]
    assert cli.main(argv, owns_process=False) == 0, capsys.readouterr().err
    assert len(reads) == 1


def test_commands_that_only_read_do_not_import_torch(tmp_path: Path) -> None:
    """``status`` as its own process (the console script's owner path) never imports torch (~2 s of start-up)."""
    import subprocess
    import sys

    make_study(open_storage(str(tmp_path / "j.log"), STUDY, artifacts=tmp_path / "store"), STUDY)
    code = ("import sys; from autotune import cli; sys.argv = ['autotune', 'status', 'demo', '--storage', 'j.log']; "
            "rc = cli.main(); print('torch' in sys.modules); sys.exit(rc)")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "False"


def test_a_writer_cuts_off_a_torn_record_a_dead_writer_left(journal_lines: list[bytes], tmp_path: Path) -> None:
    """A driver killed mid-append leaves a torn last line. The next writer (a resumed ``launch``) cuts it off,
    saying so, before appending: otherwise its first record glues onto the fragment and becomes a middle
    line no reader can apply, and every trial behind it is lost to ``status``/``best``/``compare``."""
    from autotune.search.storage import JournalRepairedWarning

    path = tmp_path / "j.log"
    whole = b"".join(journal_lines)
    path.write_bytes(whole + b'{"op_code": 8, "worker_id": "w", "trial_id": 0, "user_attr": {"x"')
    with pytest.warns(JournalRepairedWarning, match=r"cut off a torn last record \(\d+ bytes"):
        storages = open_storage(str(path), STUDY)
    assert path.read_bytes() == whole
    study = optuna.load_study(study_name=STUDY, storage=storages.storage)
    study.set_user_attr("resumed", True)  # the resumed driver's first append
    again = open_storage(str(path), STUDY, read_only=True)
    assert read_study(again, STUDY).user_attrs["resumed"] is True
    assert len(read_study(again, STUDY).trials) == len(read_study(open_storage(str(path), STUDY), STUDY).trials)


def test_a_writer_refuses_a_journal_whose_last_complete_line_is_damage(
    journal_lines: list[bytes], tmp_path: Path
) -> None:
    """Optuna's own reader skips a bad last line, so a writer would bury it: it is refused, naming the line."""
    path = tmp_path / "j.log"
    path.write_bytes(b"".join(journal_lines) + b'{"op_code": 4, "worker_id": "w", "tri\n')
    with pytest.raises(StorageError, match=f"damaged journal: line {len(journal_lines) + 1} is not a journal record"):
        open_storage(str(path), STUDY)
    assert path.read_bytes().endswith(b'"tri\n')  # left as it was


def test_a_writer_clears_a_lock_a_killed_writer_left(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, recwarn: pytest.WarningsRecorder
) -> None:
    """A driver SIGKILLed while appending leaves the journal's lock. Optuna's lock is a symlink to the journal
    whose grace period reads the age through the link: taken through a relative path (``runs/S/journal.log``
    from the launch directory) the link points nowhere and the resumed driver waited on it for ever (seen in
    CI). Writers now link the absolute path, so the grace period works, and a dangling lock an older writer
    left is removed once it is as old as that grace period."""
    import threading

    from autotune.search import storage as storage_module
    from autotune.search.storage import JournalRepairedWarning

    monkeypatch.chdir(tmp_path)
    journal = Path("runs") / STUDY / "journal.log"
    storages = open_storage(str(journal), STUDY)
    make_study(storages, STUDY)
    lock = storages.storage._backend._lock  # type: ignore[attr-defined]  # noqa: SLF001 - a killed writer's
    lock.acquire()  # ... and never releases
    held = tmp_path / "runs" / STUDY / "journal.log.lock"
    assert Path(os.readlink(held)).is_absolute() and held.exists()
    held.unlink()

    def opened_within(seconds: float) -> bool:
        thread = threading.Thread(target=open_storage, args=(str(journal), STUDY), daemon=True)
        thread.start()
        thread.join(seconds)
        return not thread.is_alive()

    held.symlink_to(journal)  # what the old code left: relative, so it resolves beside itself, to nothing
    assert not held.exists()
    os.utime(held, (time.time() - 60, time.time() - 60), follow_symlinks=False)  # left a minute ago
    assert opened_within(20) and not held.is_symlink()
    assert any(isinstance(w.message, JournalRepairedWarning) and "journal.log.lock" in str(w.message) for w in recwarn)
    monkeypatch.setattr(storage_module, "LOCK_GRACE_S", 2)
    held.symlink_to(journal)  # just left: a writer waits out the grace period, then goes on
    t0 = time.monotonic()
    assert opened_within(20) and not held.is_symlink() and time.monotonic() - t0 >= 1.5
    assert read_study(open_storage(str(journal), STUDY, read_only=True), STUDY).trials
