"""optuna-dashboard on a study's storage: serve it on 127.0.0.1, and attach report figures and a note to a study.

The only module importing ``optuna_dashboard``. The server is the dashboard's WSGI app with the
study's artifact store attached (trained nets and net.js downloadable per trial), on wsgiref with
one thread per request (the page fires many API calls at once), no access log on the terminal.
It serves read-only: every request that would change the storage (create, rename or delete a
study, notes, tell, user attrs, uploads: any method but GET/HEAD) is answered 403 with the reason,
which the page shows — the storage it is given is opened read-only too.
"""

from __future__ import annotations

import json
import socketserver
from collections.abc import Callable, Iterable, Mapping
from typing import Any
from wsgiref.simple_server import WSGIRequestHandler, WSGIServer, make_server

from autotune.search.storage import StorageError, Storages, load_study

__all__ = ["READ_METHODS", "DashboardServer", "attach", "read_only_app"]

READ_METHODS = ("GET", "HEAD")
"""The HTTP methods the read-only dashboard answers; optuna-dashboard writes with POST, PUT and DELETE."""


class _QuietHandler(WSGIRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:  # no access log on the terminal
        pass


class _ThreadingWSGIServer(socketserver.ThreadingMixIn, WSGIServer):
    """wsgiref's server, one thread per request."""

    daemon_threads = True


def read_only_app(app: Callable[..., Iterable[bytes]], storage: str) -> Callable[..., Iterable[bytes]]:
    """The WSGI ``app`` answering every request but ``READ_METHODS`` with 403 and a reason naming ``storage``."""
    reason = json.dumps({"reason": f"read-only: autotune dashboard does not change the storage {storage}"}).encode()

    def guarded(environ: dict[str, Any], start_response: Callable[..., Any]) -> Iterable[bytes]:
        if environ.get("REQUEST_METHOD", "GET") in READ_METHODS:
            return app(environ, start_response)
        start_response("403 Forbidden", [("Content-Type", "application/json"), ("Content-Length", str(len(reason)))])
        return [reason]

    return guarded


class DashboardServer:
    """optuna-dashboard for ``storages``, read-only, on 127.0.0.1:``port`` (0: any free port), not yet serving.

    ``study_name`` (may be '') must exist in the storage (``UnknownStudyError`` listing the ones it
    has); the URL then opens that study's page. A port that cannot be bound is a ``StorageError``.
    """

    def __init__(self, storages: Storages, study_name: str, port: int) -> None:
        import optuna_dashboard

        if study_name:
            load_study(storages, study_name)  # an unknown name fails now, listing the storage's studies
        self.app = read_only_app(
            optuna_dashboard.wsgi(storages.storage, artifact_store=storages.artifacts), storages.url
        )
        """The WSGI application served: optuna-dashboard behind ``read_only_app``."""
        try:
            self._server = make_server(
                "127.0.0.1", port, self.app, server_class=_ThreadingWSGIServer, handler_class=_QuietHandler
            )
        except OSError as exc:  # e.g. the port is taken
            raise StorageError(
                f"dashboard: cannot listen on 127.0.0.1:{port} ({exc.strerror or exc}); try --port"
            ) from None
        self.url = f"http://127.0.0.1:{self._server.server_port}/"
        """Where the dashboard answers (the study's page when a study was named)."""
        if study_name:
            self.url += f"dashboard/studies/{storages.storage.get_study_id_from_name(study_name)}"

    def serve_forever(self) -> None:
        """Serve until Ctrl-C, then close the socket."""
        with self._server:
            try:
                self._server.serve_forever()
            except KeyboardInterrupt:
                pass

    def close(self) -> None:
        """Close the listening socket (a server that will not serve, or has served)."""
        self._server.server_close()


def attach(storages: Storages, study_name: str, figures: Mapping[str, Any], note: str) -> list[str]:
    """Store plotly ``figures`` ({graph id: figure}; a stored id is replaced) and a markdown ``note`` in the study.

    Returns the graph ids stored, in the order given.
    """
    from optuna_dashboard import save_note, save_plotly_graph_object

    study = load_study(storages, study_name)
    ids = [save_plotly_graph_object(study, figure, graph_object_id=key) for key, figure in figures.items()]
    save_note(study, note)
    return ids
