"""The live view's server: one page of our own on 127.0.0.1, each report pushed as it comes.

Standard library only: :class:`http.server.ThreadingHTTPServer` serves the page (HTML, JS and
CSS shipped as package data, nothing from elsewhere) and a Server-Sent Events stream
(``GET /events``). SSE rather than a WebSocket: the messages go one way (server to page),
the browser's ``EventSource`` reconnects by itself, and it is plain HTTP, so no WebSocket
library is needed (the package depends on none) and there is no handshake or framing to
hand-write.

Read only: ``GET`` and ``HEAD`` of the page, its two files and the stream; every other method
is refused (405), every other path is 404, and a request whose ``Host`` is not this server's
loopback address is refused (403: a page elsewhere cannot reach it through a DNS name
rebound to 127.0.0.1). It binds 127.0.0.1 only.

A late visitor gets the history at once: the last ``history`` messages (the reports), the
identified response, the supervisor's mode and each model's diagnosis in force where they are
older, and, per model,
the latest window's spectrum, then the live stream.
"""

from __future__ import annotations

import contextlib
import http.server
import json
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Mapping
from importlib import resources
from typing import Any

from twotank_validation.online.window import WindowReport
from twotank_validation.view.messages import report_message, spectrum

HOST = "127.0.0.1"
"""The only address the view listens on."""
DEFAULT_HISTORY = 2000
"""Messages a late visitor gets at once (about 14 h of two models' quarter-period windows at
the default 204.8 s period)."""
CLIENT_QUEUE = 20000
"""Messages a page may fall behind by before its stream is closed (it reconnects and gets the
history anew)."""
SPECTRUM_EVERY_S = 0.1
"""A page gets each model's latest spectrum at most this often (the reports themselves go at
once): a replay as fast as it goes makes hundreds a second, which no page could draw."""
STICKY = frozenset({"mode", "diagnosis", "response"})
"""Messages that hold until the next of their kind (per model): a late visitor gets the latest
of each even when it is older than the history (``response``: the identified frequency
response, ``--view-response``, sent once at the start)."""
KEEPALIVE_S = 10.0
"""A comment line on an idle stream this often, so that a page that went away is noticed."""
_FILES = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/view.js": ("view.js", "text/javascript; charset=utf-8"),
    "/view.css": ("view.css", "text/css; charset=utf-8"),
}
_CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; "
    "img-src 'self' data:; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
)
"""The page may load and connect to nothing but this server."""


def _static(name: str) -> bytes:
    return (resources.files("twotank_validation.view") / "static" / name).read_bytes()


def _json(doc: Mapping[str, Any]) -> str:
    return json.dumps(doc, allow_nan=False, separators=(",", ":"))


_NOTHING = object()
"""Nothing came from a page's queue."""


class _Due:
    """Queue marker: the model's latest spectrum is due (serialised when it is sent)."""

    __slots__ = ("model",)

    def __init__(self, model: str) -> None:
        self.model = model


class _Client:
    """One page's stream: what waits for it (a message, a spectrum due, None: close)."""

    def __init__(self) -> None:
        self.queue: queue.Queue[str | _Due | None] = queue.Queue(CLIENT_QUEUE)
        self.dropped = False


class ViewServer:
    """Serve the live view on ``http://127.0.0.1:PORT/`` and push messages to every page.

    Args:
        port: TCP port on 127.0.0.1; 0: any free one (:attr:`url` names it).
        history: messages a late visitor gets at once (the latest spectrum of each model
            besides).
        title: the page's heading (e.g. the recording or ``live``).
        models: per model, its band (``Band.to_dict()`` or None) for the per-bin plot.
        hop_s: data seconds between two windows (the page's "stopped" sign waits
            ``hop_s / speed`` wall seconds); None: the page learns it from the reports.
        speed: data seconds per wall second (a paced replay's ``--replay-speed``; 1 live);
            ``inf``: as fast as possible.
        stale_after_s: wall seconds without a report after which the page says the reports
            stopped (overrides ``hop_s / speed``).

    Use as a context manager, or :meth:`start` and :meth:`close`. :meth:`publish_report` is
    the listener to hand to ``on_report``; it is thread-safe and does not block on pages.

    Each report goes out as its message (:func:`~.messages.report_message`, without the
    spectrum) at once; its spectrum (a few thousand numbers) is serialised when a page's
    stream sends it, and only the latest of each model: a page that falls behind (a replay
    as fast as it goes) skips the spectra it could not show anyway, and the validator's
    thread never serialises one. A page gets each model's latest spectrum at most every
    :data:`SPECTRUM_EVERY_S`.
    """

    def __init__(
        self,
        port: int = 0,
        *,
        history: int = DEFAULT_HISTORY,
        title: str = "",
        models: Mapping[str, Mapping[str, Any] | None] | None = None,
        hop_s: float | None = None,
        speed: float = 1.0,
        stale_after_s: float | None = None,
    ) -> None:
        if history < 1:
            raise ValueError(f"history {history} must be >= 1")
        self._lock = threading.Lock()
        self._history: deque[tuple[int, str]] = deque(maxlen=history)  # (seq, JSON)
        # the latest message of each kind that stays true until the next (the supervisor's
        # mode; a model's diagnosis on its own topic): (type, model) -> (seq, JSON)
        self._sticky: dict[tuple[str, str], tuple[int, str]] = {}
        # model -> (seq, report, start_ns) of its latest judged report; its JSON once made
        self._spectra: dict[str, tuple[int, WindowReport, int]] = {}
        self._spectrum_json: dict[str, tuple[int, str]] = {}
        self._clients: list[_Client] = []
        self._seq = 0
        self._hello: dict[str, Any] = {
            "type": "hello",
            "title": title,
            "models": {k: (dict(v) if v is not None else None) for k, v in (models or {}).items()},
            "hop_s": hop_s,
            "speed": None if math.isinf(speed) else speed,
            "stale_after_s": stale_after_s,
            "history": history,
        }
        self._ended: str | None = None
        self.published = 0
        pages = {path: (_static(name), ctype) for path, (name, ctype) in _FILES.items()}
        self._httpd = http.server.ThreadingHTTPServer((HOST, port), _handler(self, pages))
        self._httpd.daemon_threads = True
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        """The TCP port it listens on (127.0.0.1)."""
        return int(self._httpd.server_address[1])

    @property
    def url(self) -> str:
        """``http://127.0.0.1:PORT/``."""
        return f"http://{HOST}:{self.port}/"

    def start(self) -> ViewServer:
        """Serve in a background thread (daemon); returns self."""
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._httpd.serve_forever, name="twotank-view", daemon=True
            )
            self._thread.start()
        return self

    def close(self) -> None:
        """Close every page's stream and stop serving."""
        with self._lock:
            for c in self._clients:
                with contextlib.suppress(queue.Full):
                    c.queue.put_nowait(None)
            self._clients.clear()
        if self._thread is not None:
            self._httpd.shutdown()
            self._thread.join(timeout=5.0)
            self._thread = None
        self._httpd.server_close()

    def __enter__(self) -> ViewServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def publish_report(self, rep: WindowReport, start_ns: int = 0) -> None:
        """Push a report to every page and keep it (its spectrum: the model's latest).

        The message is :func:`~.messages.report_message`'s (the ``validate --json`` window
        entry and the model's name) with ``seq`` and ``sent``; a judged window's spectrum
        follows as a ``"spectrum"`` message (:meth:`spectrum_message`).
        """
        doc = report_message(rep, start_ns, with_spectrum=False)
        judged = rep.judged and rep.freqs_hz.size > 0
        with self._lock:
            seq = self._stamp(doc)
            self._history.append((seq, light := _json(doc)))
            if judged:
                self._spectra[rep.model] = (seq, rep, start_ns)
            self._send(light, _Due(rep.model) if judged else None)

    def publish(self, message: Mapping[str, Any]) -> None:
        """Push a message (a JSON object with a ``"type"``) to every page and keep it.

        It gets ``seq`` (1, 2, ...) and ``sent`` (wall clock, s since the epoch, when it was
        pushed: the page's latency is measured from it).
        """
        doc = dict(message)
        with self._lock:
            seq = self._stamp(doc)
            self._history.append((seq, data := _json(doc)))
            if doc.get("type") in STICKY:
                self._sticky[(str(doc["type"]), str(doc.get("model", "")))] = (seq, data)
            self._send(data, None)

    def _stamp(self, doc: dict[str, Any]) -> int:
        """Number and stamp a message (lock held); its seq."""
        self._seq += 1
        doc["seq"] = self._seq
        doc["sent"] = time.time()
        self.published += 1
        return self._seq

    def spectrum_message(self, model: str) -> str | None:
        """The JSON of ``model``'s latest spectrum (made once per report), None if none.

        ``{"type": "spectrum", "model", "seq"`` (its report's), ``"start", "end", "beta",
        "noise_beta", "freqs_hz", "w_min"}`` (:func:`~.messages.spectrum`).
        """
        with self._lock:
            latest = self._spectra.get(model)
            made = self._spectrum_json.get(model)
        if latest is None:
            return None
        seq, rep, start_ns = latest
        if made is not None and made[0] == seq:
            return made[1]
        entry = report_message(rep, start_ns, with_spectrum=False)
        doc = {"type": "spectrum", "model": model, "seq": seq}
        doc |= {k: entry[k] for k in ("start", "end", "beta", "noise_beta")}
        data = _json(doc | spectrum(rep))
        with self._lock:
            self._spectrum_json[model] = (seq, data)
        return data

    def end(self, text: str) -> None:
        """Say the run ended (``text``: why, e.g. "replay finished"); the page keeps it."""
        with self._lock:
            self._ended = text
            self._send(_json({"type": "end", "text": text, "sent": time.time()}), None)

    def _send(self, data: str, due: _Due | None) -> None:
        """Queue ``data`` (and a spectrum due) for every page (lock held).

        A page too far behind is dropped (it reconnects and gets the history anew).
        """
        for c in self._clients:
            try:
                c.queue.put_nowait(data)
                if due is not None:
                    c.queue.put_nowait(due)
            except queue.Full:
                c.dropped = True
        self._clients = [c for c in self._clients if not c.dropped]

    def subscribe(self) -> tuple[list[str], _Client]:
        """A new page's first messages (hello, history, latest spectra, end) and its queue."""
        client = _Client()
        with self._lock:
            oldest = self._history[0][0] if self._history else self._seq + 1
            # a mode or diagnosis older than the history still holds: it goes first
            kept = sorted(v for v in self._sticky.values() if v[0] < oldest)
            first = [_json(self._hello), *(m for _, m in kept), *(m for _, m in self._history)]
            models = sorted(self._spectra)
            ended = self._ended
            self._clients.append(client)
        first += [m for m in map(self.spectrum_message, models) if m is not None]
        if ended is not None:
            first.append(_json({"type": "end", "text": ended, "sent": time.time()}))
        return first, client

    def unsubscribe(self, client: _Client) -> None:
        """Forget a page that went away."""
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)


def _handler(
    view: ViewServer, pages: Mapping[str, tuple[bytes, str]]
) -> type[http.server.BaseHTTPRequestHandler]:
    class Handler(http.server.BaseHTTPRequestHandler):
        server_version = "twotank-view"
        sys_version = ""
        protocol_version = "HTTP/1.1"

        def log_message(self, format: str, *args: Any) -> None:
            """Quiet: the command's output is its reports."""

        def _host_ok(self) -> bool:
            host = (self.headers.get("Host") or "").strip().lower()
            return host in {f"{HOST}:{view.port}", f"localhost:{view.port}"}

        def _refuse(self, code: int, text: str, allow: bool = False) -> None:
            body = (text + "\n").encode()
            self.send_response(code)
            if allow:
                self.send_header("Allow", "GET, HEAD")
            self.send_header("Content-Type", "text/plain; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Connection", "close")
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)
            self.close_connection = True

        def _read_only(self) -> None:
            self._refuse(405, "read only: the view changes nothing (GET and HEAD only)", True)

        def __getattr__(self, name: str) -> Any:
            # every method but GET and HEAD (POST, PUT, DELETE, ... any name) is refused
            if name.startswith("do_"):
                return self._read_only
            raise AttributeError(name)

        def do_HEAD(self) -> None:
            self.do_GET()

        def do_GET(self) -> None:
            if not self._host_ok():
                self._refuse(403, "the view answers only to 127.0.0.1 or localhost")
                return
            path = self.path.split("?", 1)[0]
            if path == "/events":
                self._stream()
                return
            page = pages.get(path)
            if page is None:
                self._refuse(404, "not found: the view is / and /events")
                return
            body, ctype = page
            self.send_response(200)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Content-Security-Policy", _CSP)
            self.send_header("X-Content-Type-Options", "nosniff")
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)

        def _stream(self) -> None:
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream; charset=utf-8")
            self.send_header("Cache-Control", "no-store")
            self.send_header("Connection", "close")
            self.end_headers()
            self.close_connection = True
            if self.command == "HEAD":
                return
            first, client = view.subscribe()
            try:
                self.wfile.write("".join(f"data: {m}\n\n" for m in first).encode())
                self.wfile.flush()
                due: list[str] = []  # models whose latest spectrum is still to go
                next_spectra = 0.0  # monotonic time the next spectra may go
                while True:
                    wait = KEEPALIVE_S if not due else next_spectra - time.monotonic()
                    parts: list[str] = []
                    closing = idle = False
                    try:
                        item = client.queue.get(timeout=wait) if wait > 0 else _NOTHING
                    except queue.Empty:
                        item, idle = _NOTHING, not due
                    while item is not _NOTHING:  # what else waits goes in the same write
                        if item is None or client.dropped:
                            closing = True
                            break
                        if isinstance(item, _Due):
                            if item.model not in due:
                                due.append(item.model)
                        elif isinstance(item, str):
                            parts.append(item)
                        if len(parts) >= 256:
                            break
                        try:
                            item = client.queue.get_nowait()
                        except queue.Empty:
                            item = _NOTHING
                    if due and time.monotonic() >= next_spectra:
                        parts += [m for m in map(view.spectrum_message, due) if m is not None]
                        due = []
                        next_spectra = time.monotonic() + SPECTRUM_EVERY_S
                    if parts:
                        self.wfile.write("".join(f"data: {m}\n\n" for m in parts).encode())
                        self.wfile.flush()
                    elif idle:
                        self.wfile.write(b": keepalive\n\n")
                        self.wfile.flush()
                    if closing:
                        return
            except (BrokenPipeError, ConnectionResetError, TimeoutError):
                return
            finally:
                view.unsubscribe(client)

    return Handler
