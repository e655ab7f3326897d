"""The validator's reports over the Foxglove WebSocket protocol (``--foxglove``; docs/view.md).

One more listener of the same reports as the page (:class:`~.server.ViewServer`): each report
is logged, as it comes, on channels of the Foxglove SDK (``foxglove-sdk``, imported on first
use), whose server speaks the protocol on 127.0.0.1 only (subprotocol ``foxglove.sdk.v1``,
the ``foxglove.websocket.v1`` messages under their new name). Per model M, JSON messages
with a JSON Schema:

* ``/validation/M/report``: the ``validate --json`` window entry
  (:func:`~.messages.report_message` without the spectrum: β, β_op, β_total, the alarm,
  judged or why not, the window's start and end in s, the diagnosis in force);
* ``/validation/M/w_min``: the judged window's per-bin minimum ‖W(n)‖ above 0 Hz,
  ``freqs_hz`` and ``w_min`` as arrays of numbers (a Plot panel's "path (current)" x axis);
* ``/validation/M/diagnosis``: the diagnosis (``LiveDiagnosis.to_json``) when a window
  carries a new one (its ``update`` or onset changed) or, attached to a running system
  (``view``), each Diagnosis message.

Each message's timestamp is its window's end in the recording's (or the simulation's) time,
in ns. Numbers that JSON cannot carry (NaN, inf) are null, as in ``validate --json``.

The SDK's server keeps no history: a client sees the reports from its subscription on. A
replay therefore waits for a client's subscription before it starts
(:meth:`FoxgloveView.wait_for_client`).
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from twotank_validation.online.window import WindowReport
from twotank_validation.view.messages import report_message

HOST = "127.0.0.1"
"""The only address the Foxglove server listens on."""
SUBPROTOCOL = "foxglove.sdk.v1"
"""The WebSocket subprotocol the SDK's server accepts."""
SETTLE_S = 0.5
"""After a client's first subscription, the wait for the rest of its subscriptions (a client
subscribes to the channels its panels use, in one message or a few)."""

_NUMBER = {"type": ["number", "null"]}
_TEXT = {"type": ["string", "null"]}
DIAGNOSIS_SCHEMA: dict[str, Any] = {
    "title": "twotank_validation.Diagnosis",
    "description": "The most likely effect behind a model's alarm (docs/diagnosis.md).",
    "type": "object",
    "properties": {
        "model": {"type": "string"},
        "kind": {"type": "string"},
        "channel": {"type": "string"},
        "parameters": {"type": "object", "additionalProperties": {"type": "number"}},
        "probability": _NUMBER,
        "score": {"type": "number"},
        "onset": {"type": "number", "description": "s of the data's time base"},
        "window_end": {"type": "number", "description": "s of the data's time base"},
        "windows": {"type": "integer"},
        "update": {"type": "integer"},
        "summary": {"type": "string"},
    },
}
REPORT_SCHEMA: dict[str, Any] = {
    "title": "twotank_validation.WindowReport",
    "description": "One window of one model: the validate --json window entry (docs/cli.md).",
    "type": "object",
    "properties": {
        "model": {"type": "string"},
        "start": {"type": "number", "description": "window start, s from the data's start"},
        "end": {"type": "number", "description": "window end, s from the data's start"},
        "beta": {**_NUMBER, "description": "min ||w|| over the band's bins; null: not judged"},
        "beta_op": _NUMBER,
        "beta_total": _NUMBER,
        "margin": _NUMBER,
        "invalidated": {"type": "boolean"},
        "alarm": {"type": "string", "enum": ["OK", "WARN", "ERROR", "STALE"]},
        "reason": _TEXT,
        "data_quality": {"type": "string"},
        "warnings": {"type": "array", "items": {"type": "string"}},
        "input_leakage": _NUMBER,
        "input_change": _NUMBER,
        "input_noise": _NUMBER,
        "input_noise_effect": _NUMBER,
        "noise_beta": _NUMBER,
        "raised_by": {"type": "string"},
        "operating_point": {"type": "string"},
        "op_state": _TEXT,
        "beta_outside": _NUMBER,
        "lines_outside": {"type": "array", "items": {"type": "array", "items": _NUMBER}},
        "diagnosis": {"oneOf": [{"type": "null"}, DIAGNOSIS_SCHEMA]},
        "n_periods": {"type": "integer"},
        "convention": {"type": "string"},
    },
}
W_MIN_SCHEMA: dict[str, Any] = {
    "title": "twotank_validation.WMin",
    "description": "A judged window's per-bin minimum ||W(n)|| above 0 Hz (units of w).",
    "type": "object",
    "properties": {
        "model": {"type": "string"},
        "end": {"type": "number", "description": "window end, s from the data's start"},
        "freqs_hz": {"type": "array", "items": {"type": "number"}},
        "w_min": {"type": "array", "items": _NUMBER},
    },
}
CHANNELS: dict[str, dict[str, Any]] = {
    "report": REPORT_SCHEMA,
    "w_min": W_MIN_SCHEMA,
    "diagnosis": DIAGNOSIS_SCHEMA,
}
"""Per model M, the channel ``/validation/M/<key>`` and its JSON Schema."""


def topic(model: str, kind: str) -> str:
    """The channel of ``model``'s ``kind`` (a key of :data:`CHANNELS`)."""
    return f"/validation/{model}/{kind}"


def _finite(values: np.ndarray) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in values.tolist()]


def w_min_message(rep: WindowReport, start_ns: int = 0) -> dict[str, Any]:
    """A judged window's per-bin minimum ‖W(n)‖ above 0 Hz (non-finite values: null)."""
    keep = rep.freqs_hz > 0
    return {
        "model": rep.model,
        "end": (rep.end_ns - start_ns) / 1e9,
        "freqs_hz": _finite(rep.freqs_hz[keep]),
        "w_min": _finite(rep.w_min[keep]),
    }


def _listener(on_subscribe: Callable[[], None]) -> Any:
    """The SDK's ServerListener that calls ``on_subscribe()`` at each subscription.

    (Its other callbacks keep the protocol's defaults, which do nothing: clients can only
    subscribe, the server offers nothing else.)
    """
    from foxglove.websocket import ChannelView, Client, ServerListener  # noqa: PLC0415

    class Listener(ServerListener):
        def on_subscribe(self, client: Client, channel: ChannelView) -> None:
            on_subscribe()

    return Listener()


def _encode(doc: Mapping[str, Any]) -> bytes:
    return json.dumps(doc, allow_nan=False, separators=(",", ":")).encode("utf-8")


class FoxgloveView:
    """Serve the reports over the Foxglove WebSocket protocol on ``ws://127.0.0.1:PORT``.

    Args:
        port: TCP port on 127.0.0.1; 0: any free one (:attr:`port` names it).
        models: the models whose channels are advertised at once (others when their first
            report comes).
        name: the server's name in the client.

    Raises:
        RuntimeError: the SDK could not start the server (the port is taken, ...).

    :meth:`publish_report` is the listener (thread-safe: the SDK's channels are); the SDK
    sends from its own threads and drops the oldest messages of a client that falls behind.
    """

    def __init__(self, port: int = 0, *, models: Iterable[str] = (), name: str = "twotank") -> None:
        import foxglove  # noqa: PLC0415 (imported on first use)

        self._foxglove = foxglove
        self._context = foxglove.Context()
        self._lock = threading.Lock()
        self._channels: dict[tuple[str, str], Any] = {}
        self._diagnosis: dict[str, tuple[int, int]] = {}  # model -> (onset_ns, update) logged
        self._subscribed = threading.Event()
        self.subscriptions = 0
        """Subscriptions clients made so far."""
        for m in models:
            self._model_channels(m)
        self._server = foxglove.start_server(
            name=name,
            host=HOST,
            port=port,
            context=self._context,
            server_listener=_listener(self._on_subscribe),
            capabilities=[],
        )

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self._server.port)

    @property
    def url(self) -> str:
        """``ws://127.0.0.1:PORT``."""
        return f"ws://{HOST}:{self.port}"

    def close(self) -> None:
        """Stop the server."""
        self._server.stop()

    def __enter__(self) -> FoxgloveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _on_subscribe(self) -> None:
        with self._lock:
            self.subscriptions += 1
        self._subscribed.set()

    def wait_for_client(self, stop: Callable[[], bool] = lambda: False) -> bool:
        """Block until a client has subscribed (then :data:`SETTLE_S` more); False: ``stop()``."""
        while not self._subscribed.wait(0.1):
            if stop():
                return False
        time.sleep(SETTLE_S)
        return True

    def _model_channels(self, model: str) -> dict[str, Any]:
        with self._lock:
            out = {}
            for kind, schema in CHANNELS.items():
                key = (model, kind)
                if key not in self._channels:
                    self._channels[key] = self._foxglove.Channel(
                        topic(model, kind), schema=schema, context=self._context
                    )
                out[kind] = self._channels[key]
            return out

    def publish_report(self, rep: WindowReport, start_ns: int = 0) -> None:
        """Log a report (and its spectrum, and a new diagnosis) at its window's end."""
        ch = self._model_channels(rep.model)
        msg = report_message(rep, start_ns, with_spectrum=False)
        del msg["type"]
        ch["report"].log(_encode(msg), log_time=rep.end_ns)
        if rep.judged and rep.freqs_hz.size:
            ch["w_min"].log(_encode(w_min_message(rep, start_ns)), log_time=rep.end_ns)
        d = rep.diagnosis
        if d is not None and self._diagnosis.get(rep.model) != (d.onset_ns, d.update):
            self._diagnosis[rep.model] = (d.onset_ns, d.update)
            doc = {"model": rep.model, **d.to_json()}
            ch["diagnosis"].log(_encode(doc), log_time=rep.end_ns)

    def publish(self, message: Mapping[str, Any]) -> None:
        """A message of the page's stream: a ``"diagnosis"`` one goes to its channel.

        (``view`` attached to a running system hands each Diagnosis message this way.)
        """
        if message.get("type") != "diagnosis":
            return
        model = str(message["model"])
        diag = dict(message["diagnosis"])
        end_ns = round(float(diag["window_end"]) * 1e9)
        self._model_channels(model)["diagnosis"].log(
            _encode({"model": model, **diag}), log_time=end_ns
        )
