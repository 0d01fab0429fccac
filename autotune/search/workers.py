"""The Ray side of a study: long-lived trial workers and the pool the driver multiplexes (the only Ray module).

Why long-lived: a fresh process spends 20–25 s loading/compiling the numba kernels before its first
trial, a warm one trains and scores ``network_basic_v2`` in about 6 s — so each worker is one Ray
actor that warms up once (``configure_process`` + a tiny trial) and then runs trial after trial.

A worker runs a trial in a background thread (``run_trial``) and turns each intermediate score into
an event; the trial thread then blocks until the driver answers prune or go on. The actor is
threaded (``max_concurrency``) so ``next_event`` and ``answer`` are served while the trial runs.
``WorkerPool`` keeps one outstanding ``next_event`` call per busy worker and waits on all of them
with ``ray.wait``: the driver sees plain Python events and never touches Ray. Workers need no
storage credentials and a cluster needs no shared filesystem — only settings, seeds, scores and
the trained net's text cross the wire.

Ray's lifecycle: ``address=None`` starts a private local Ray instance (no dashboard, worker logs
not forwarded); ``address="host:port"`` joins an existing cluster. A local instance is recorded in
``<state_dir>/ray/<host>-<pid>.json`` (driver pid, session dir, Ray's own process ids): a driver
killed with SIGKILL leaves Ray's agents behind, so the next pool on this host ends the processes
of every recorded session whose driver is dead, and a normal ``close`` ends its own.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import queue
import signal
import socket
import threading
import time
from pathlib import Path
from typing import Any

import ray

from autotune.search.objective import TrialOutcome, TrialTask, process_alive, process_start, run_trial, worker_id

__all__ = ["Event", "WorkerPool", "TrialWorker", "kill_stale_sessions", "WARM_UP_TASK"]

# a few hundred decisions and a tiny net: loads every compiled kernel a trial uses (training, quick
# evaluation, the official evaluation) so the first real trial's timings are the steady state
WARM_UP_TASK = TrialTask(
    number=-1,
    config={"ruleset": "v2", "patches_ahead": 2, "train_iterations": 200, "temporal_window": 0,
            "experience_size": 100, "start_learn_threshold": 20, "layers": "fc:2:relu", "batch_size": 4},
    seed=0, report_points=1, quick_runs=1, quick_frames=100,
)  # fmt: skip


class TrialWorker:
    """One long-lived worker process: warm once, then trials one after another (a threaded Ray actor)."""

    def __init__(self, threads: int = 1) -> None:
        from autotune import configure_process

        configure_process(threads=max(1, int(threads)), numba_threads=max(1, int(threads)))
        self._events: queue.Queue[tuple[Any, ...]] = queue.Queue()
        self._answers: queue.Queue[bool] = queue.Queue()
        self._thread: threading.Thread | None = None

    def info(self) -> dict[str, Any]:
        """Who runs the trials: host, pid, ``host:pid`` (tests SIGKILL this pid) and the Ray node id."""
        node = ray.get_runtime_context().get_node_id()
        return {"host": socket.gethostname(), "pid": os.getpid(), "worker": worker_id(), "node": node}

    def warm_up(self) -> float:
        """Run a tiny trial (compiles or loads every kernel a trial needs); returns its wall seconds."""
        t0 = time.perf_counter()
        run_trial(WARM_UP_TASK, lambda k, frames, score: False)
        return time.perf_counter() - t0

    def warm_up_and_info(self) -> dict[str, Any]:
        """``warm_up`` then ``info`` (a replacement worker reports itself ready with its new pid)."""
        seconds = self.warm_up()
        return {**self.info(), "warm_up_seconds": seconds}

    def start(self, task: TrialTask) -> None:
        """Begin ``task`` in the background; its events come out of ``next_event``."""
        if self._thread is not None and self._thread.is_alive():
            raise RuntimeError(f"worker {worker_id()} is still running a trial")
        self._thread = threading.Thread(target=self._run, args=(task,), name=f"trial-{task.number}", daemon=True)
        self._thread.start()

    def next_event(self) -> tuple[Any, ...]:
        """Block until the trial reports — ``("report", k, frames, score)`` — or ends — ``("done", outcome)``."""
        return self._events.get()

    def answer(self, prune: bool) -> None:
        """Let the trial waiting at its report go on (False) or stop it as pruned (True)."""
        self._answers.put(bool(prune))

    def _run(self, task: TrialTask) -> None:
        def report(k: int, frames: int, score: float) -> bool:
            self._events.put(("report", k, frames, score))
            return self._answers.get()

        self._events.put(("done", run_trial(task, report)))


@dataclasses.dataclass(frozen=True)
class Event:
    """What a worker slot has to say: a report awaiting an answer, a finished trial, or a lost worker."""

    kind: str
    """``"report"`` (answer it with ``WorkerPool.answer``), ``"done"``, ``"lost"`` or ``"ready"`` (slot warmed up)."""
    slot: int
    """The worker slot (0 … workers − 1)."""
    step: int = -1
    frames: int = 0
    score: float = float("nan")
    outcome: TrialOutcome | None = None
    cause: str = ""
    """Why a worker was lost (``"lost"``)."""
    retry: bool = True
    """``"lost"``: whether the trial is worth retrying (not after an out-of-memory kill: it would ask again)."""


def _descendants(pid: int) -> list[int]:
    """Every live descendant of ``pid`` (from /proc; empty elsewhere)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
            ppid = int(text[text.rindex(")") + 2 :].split()[1])
            children.setdefault(ppid, []).append(int(stat.parent.name))
        except (OSError, ValueError, IndexError):
            continue
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def kill_stale_sessions(state_dir: Path) -> list[int]:
    """End the leftover Ray processes of this host's recorded local sessions whose driver is gone.

    A record names the driver (pid + start time), Ray's session dir and the processes seen at start
    (with their start times, so a recycled pid is never hit); every one of them still alive, and
    any process with the session dir on its command line, is sent SIGKILL. Returns the pids killed.
    Records of live drivers are left alone.
    """
    killed: list[int] = []
    for record in sorted((state_dir / "ray").glob(f"{socket.gethostname()}-*.json")):
        try:
            info = json.loads(record.read_text())
        except (OSError, ValueError):
            continue
        if process_alive(int(info["driver_pid"]), info.get("driver_start")):
            continue
        session = str(info.get("session_dir") or "")
        targets = {int(p["pid"]) for p in info.get("processes", []) if process_alive(int(p["pid"]), p.get("start"))}
        if session:
            for cmd in Path("/proc").glob("[0-9]*/cmdline"):
                pid = int(cmd.parent.name)
                if session in _cmdline(pid):
                    targets.add(pid)
        for pid in sorted(targets - {os.getpid()}):
            try:
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            except OSError:
                continue
        record.unlink(missing_ok=True)
    return killed


class WorkerPool:
    """``workers`` long-lived ``TrialWorker`` actors on a local Ray instance or a cluster, as plain events."""

    def __init__(
        self,
        workers: int,
        *,
        cpus_per_trial: float = 1.0,
        gpus_per_trial: float = 0.0,
        address: str | None = None,
        state_dir: Path | None = None,
    ) -> None:
        self.workers = int(workers)
        self.cpus_per_trial = float(cpus_per_trial)
        self.gpus_per_trial = float(gpus_per_trial)
        self.address = address
        self.state_dir = state_dir
        self._record: Path | None = None
        self._actors: list[Any] = []
        self._info: list[dict[str, Any]] = []
        self._pending: dict[Any, tuple[int, str]] = {}  # ObjectRef -> (slot, "event" | "ready")
        self._ready: list[bool] = []
        self.warm_up_seconds: list[float] = []

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> None:
        """Start (or join) Ray and the workers; returns once every worker is warm."""
        if self.address is None and self.state_dir is not None:
            kill_stale_sessions(self.state_dir)
        logging.getLogger("ray").setLevel(logging.WARNING)
        if self.address is None:
            ray.init(
                address="local",
                num_cpus=max(1, round(self.workers * self.cpus_per_trial)),
                num_gpus=int(self.workers * self.gpus_per_trial + 0.999),
                include_dashboard=False,
                log_to_driver=False,
                logging_level=logging.ERROR,
                object_store_memory=128 * 1024 * 1024,
            )
        else:
            ray.init(address=self.address, log_to_driver=False, logging_level=logging.ERROR)
        if self.address is None and self.state_dir is not None:
            self._write_record()
        self._actors = [self._new_actor() for _ in range(self.workers)]
        self._ready = [False] * self.workers
        self._info = [{} for _ in range(self.workers)]
        self._info = list(ray.get([a.info.remote() for a in self._actors]))
        self.warm_up_seconds = list(ray.get([a.warm_up.remote() for a in self._actors]))
        self._ready = [True] * self.workers
        if self._record is not None:
            self._write_record()  # the workers' pids too, now that they exist

    def close(self) -> None:
        """Stop the workers and Ray (a joined cluster keeps running); kill our local Ray's leftovers."""
        for actor in self._actors:
            try:
                ray.kill(actor)
            except Exception:  # noqa: S110 - already gone
                pass
        self._actors = []
        self._pending.clear()
        if ray.is_initialized():
            ray.shutdown()
        if self._record is not None and self.state_dir is not None:
            info = json.loads(self._record.read_text())
            info["driver_pid"] = -1  # this driver is done with it: its leftovers may go now
            self._record.write_text(json.dumps(info))
            kill_stale_sessions(self.state_dir)
            self._record = None

    def __enter__(self) -> WorkerPool:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _new_actor(self) -> Any:
        actor_class = ray.remote(TrialWorker).options(
            num_cpus=self.cpus_per_trial,
            num_gpus=self.gpus_per_trial,
            max_concurrency=4,
            max_restarts=0,
            scheduling_strategy="SPREAD",
        )
        return actor_class.remote(max(1, round(self.cpus_per_trial)))

    def _write_record(self) -> None:
        assert self.state_dir is not None
        ctx = ray.get_runtime_context()
        me = os.getpid()
        pids = {*_descendants(me), *(int(i["pid"]) for i in self._info if i)}  # Ray's processes + our workers
        info = {
            "driver_pid": me,
            "driver_start": process_start(me),
            "session_dir": str(Path(ctx.get_temp_dir()) / ctx.get_session_name()),
            "processes": [{"pid": pid, "start": process_start(pid)} for pid in sorted(pids)],
            "workers": [int(i["pid"]) if i else None for i in self._info],
        }
        self._record = self.state_dir / "ray" / f"{socket.gethostname()}-{me}.json"
        self._record.parent.mkdir(parents=True, exist_ok=True)
        self._record.write_text(json.dumps(info))

    # -- trials ---------------------------------------------------------------------------
    def idle_slots(self, busy: set[int]) -> list[int]:
        """Warm slots not in ``busy``."""
        return [s for s in range(self.workers) if self._ready[s] and s not in busy]

    def worker_of(self, slot: int) -> str:
        """``host:pid`` of the worker in ``slot``."""
        return str(self._info[slot]["worker"])

    def node_of(self, slot: int) -> str:
        """The Ray node id of the worker in ``slot``."""
        return str(self._info[slot]["node"])

    def pids(self) -> list[int]:
        """The worker processes' pids, by slot."""
        return [int(i["pid"]) for i in self._info]

    def submit(self, slot: int, task: TrialTask) -> None:
        """Start ``task`` on the worker in ``slot``; its events arrive through ``poll``."""
        actor = self._actors[slot]
        actor.start.remote(task)
        self._pending[actor.next_event.remote()] = (slot, "event")

    def answer(self, slot: int, prune: bool) -> None:
        """Answer the report ``slot`` is waiting on, and listen for its next event."""
        actor = self._actors[slot]
        actor.answer.remote(prune)
        self._pending[actor.next_event.remote()] = (slot, "event")

    def poll(self, timeout: float) -> list[Event]:
        """Events ready within ``timeout`` seconds (maybe none). A lost worker is replaced (``"ready"`` once warm)."""
        if not self._pending:
            time.sleep(min(timeout, 0.05))
            return []
        ready, _ = ray.wait(list(self._pending), num_returns=1, timeout=timeout)
        if ready:  # take everything else that is ready too, without waiting
            more, _ = ray.wait(list(self._pending), num_returns=len(self._pending), timeout=0)
            ready = list(dict.fromkeys([*ready, *more]))
        events: list[Event] = []
        for ref in ready:
            slot, kind = self._pending.pop(ref)
            try:
                value = ray.get(ref)
            except ray.exceptions.OutOfMemoryError as exc:  # Ray's memory monitor killed it: the same again would be
                events.append(Event("lost", slot, retry=False, cause=(
                    f"out of memory: Ray's memory monitor killed {self._describe(slot, exc)}; the trial is not "
                    f"retried (its settings would ask for the same memory): lower [study] max_trial_memory_gb"
                )))  # fmt: skip
                self._replace(slot)
                continue
            except (ray.exceptions.RayActorError, ray.exceptions.WorkerCrashedError) as exc:
                events.append(Event("lost", slot, cause=f"worker lost: {self._describe(slot, exc)}"))
                self._replace(slot)
                continue
            if kind == "ready":
                self._info[slot] = value
                self._ready[slot] = True
                if self._record is not None:
                    self._write_record()  # the replacement's pid
                events.append(Event("ready", slot))
            elif value[0] == "report":
                _, step, frames, score = value
                events.append(Event("report", slot, step=int(step), frames=int(frames), score=float(score)))
            else:
                events.append(Event("done", slot, outcome=value[1]))
        return events

    def kill(self, slot: int) -> None:
        """Kill the worker in ``slot`` (its pending call then reports it lost, and it is replaced)."""
        ray.kill(self._actors[slot], no_restart=True)

    def _describe(self, slot: int, exc: BaseException) -> str:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return f"{self.worker_of(slot)} died ({type(exc).__name__}: {first})"

    def _replace(self, slot: int) -> None:
        try:
            ray.kill(self._actors[slot])
        except Exception:  # noqa: S110 - already gone
            pass
        self._ready[slot] = False
        self._actors[slot] = actor = self._new_actor()
        self._pending[actor.warm_up_and_info.remote()] = (slot, "ready")
