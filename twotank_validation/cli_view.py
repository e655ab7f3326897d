"""``--view`` of ``validate`` and ``live``: the live view's options, server and closing wait.

The view is one more listener of the reports the command already prints (the same
:class:`~twotank_validation.online.validator.OnlineValidator` path): :class:`ViewRun` starts
the server (:class:`~twotank_validation.view.ViewServer`, 127.0.0.1), prints its URL, paces a
replay (``--replay-speed``), pushes each report, and at the end keeps the page up until
Ctrl-C. docs/view.md.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Any

from twotank_validation.errors import TwotankError, UsageError
from twotank_validation.online import WindowReport
from twotank_validation.online.supervisor import SupervisorState, Transition
from twotank_validation.online.window import MonitorConfig

__all__ = [
    "FOXGLOVE_PORT",
    "VIEW_STOP",
    "ViewRun",
    "add_view_options",
    "live_view",
    "model_bands",
    "view_response",
]

FOXGLOVE_PORT = 8765
"""``--foxglove-port``'s default: the port Foxglove and Lichtblick propose for a connection."""
VIEW_STOP = "closing the view; the system it shows runs on (the view changes nothing)"
"""What Ctrl-C does to the ``view`` command (said on stderr): it judges nothing, so there is
no sample to finish."""


def _speed(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give the replay's speed as a number > 0 of data seconds per wall second "
            "(e.g. 60), or leave --replay-speed out to replay as fast as possible"
        )
    return value


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: give a TCP port 0 .. 65535 (0: any free one)")
    return value


def add_view_options(
    parser: argparse.ArgumentParser, *, replay: bool, port_only: bool = False
) -> None:
    """The view's options: ``--view``, ``--view-port``, ``--view-response``, ``--foxglove*``.

    ``replay``: ``--replay-speed`` besides.

    ``port_only``: without ``--view`` (the ``view`` command's: its page is always served).
    """
    if not port_only:
        parser.add_argument(
            "--view",
            action="store_true",
            help="serve a live view of the reports on http://127.0.0.1:PORT/ (the URL is "
            "printed on stderr; it stays up after the run until Ctrl-C; docs/view.md)",
        )
    parser.add_argument(
        "--view-port",
        type=_port,
        default=0,
        metavar="P",
        help="the view's port on 127.0.0.1 (0: any free one)",
    )
    parser.add_argument(
        "--view-response",
        default=None,
        metavar="FILE",
        help="show on the page the measured frequency response ± σ against the nominal ± its "
        "weight, from an identify JSON (`identify BAG --json FILE`; docs/view.md)",
    )
    parser.add_argument(
        "--foxglove",
        action="store_true",
        help="serve the reports over the Foxglove WebSocket protocol on ws://127.0.0.1:PORT "
        "(for Foxglove or Lichtblick; a replay waits for a client; docs/view.md)",
    )
    parser.add_argument(
        "--foxglove-port",
        type=_port,
        default=FOXGLOVE_PORT,
        metavar="P",
        help=f"the Foxglove server's port on 127.0.0.1 (default {FOXGLOVE_PORT}; 0: any free one)",
    )
    if replay:
        parser.add_argument(
            "--replay-speed",
            type=_speed,
            default=None,
            metavar="X",
            help="with --view or --foxglove: replay at X times real time (default: as fast as "
            "possible)",
        )


def view_response(
    args: argparse.Namespace, sources: Sequence[str], *, page: bool = True
) -> dict[str, Any] | None:
    """``--view-response FILE``'s message for the page (None without the option).

    ``sources``: the models the view shows; the file's response must have their channels
    (:func:`~twotank_validation.view.response.response_message`). ``page``: the page is
    served (``--view``; the ``view`` command's always is).

    Raises:
        UsageError: no page to show it on, the file unreadable, not an identify JSON, or
            not of the models' channels (one line naming the fix).
    """
    import json  # noqa: PLC0415
    from pathlib import Path  # noqa: PLC0415

    from twotank_validation.usecases.reading import load  # noqa: PLC0415
    from twotank_validation.view.response import ResponseError, response_message  # noqa: PLC0415

    path = getattr(args, "view_response", None)
    if path is None:
        return None
    if not page:
        raise UsageError("--view-response shows the response on the page: add --view")
    try:
        doc = json.loads(Path(path).read_text())
    except OSError as err:
        raise UsageError(f"--view-response {path}: cannot read it ({err.strerror})") from err
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UsageError(
            f"--view-response {path}: not JSON ({err}): give the file "
            "`twotank-validation identify BAG --json FILE` wrote"
        ) from err
    message = None
    for source in sources:
        try:
            model = load(source).model
        except TwotankError:
            continue  # the command says why when it loads it
        try:
            one = response_message(doc, model.input_names, model.output_names, Path(path).name)
        except ResponseError as err:
            raise UsageError(f"--view-response {path} (model {model.name}): {err}") from err
        message = message or one
    if message is None:
        raise UsageError(f"--view-response {path}: none of the models loads to match it with")
    if message["matched"] == "shape":
        print(
            f"view: {Path(path).name} names no channels; its entries are taken as "
            f"{message['outputs']} x {message['inputs']} (matched by shape)",
            file=sys.stderr,
        )
    return message


def model_bands(sources: Sequence[str], monitor: MonitorConfig | None = None) -> dict[str, Any]:
    """Model name -> the band it is judged over (``Band.to_dict()``, None: every bin).

    ``monitor``: its ``band`` (``--band``) in place of the models' own; None: their own.

    Models that do not load are left out (the command says why when it loads them).
    """
    from twotank_validation.usecases.reading import load  # noqa: PLC0415

    out: dict[str, Any] = {}
    for source in sources:
        try:
            model = load(source).model
        except TwotankError:
            continue
        band = model.band if monitor is None else monitor.band_of(model)
        out[model.name] = None if band is None else band.to_dict()
    return out


class ViewRun:
    """The view of one run: started on entry (its URL on stderr), kept up after the run.

    Args:
        port: ``--view-port``.
        title: the page's heading.
        bands: :func:`model_bands`.
        speed: ``--replay-speed`` (None: as fast as possible); ``live``: 1 (real time).
        replay: a replay is paced at ``speed``; ``live`` is not. With ``foxglove`` it
            starts once a Foxglove client has subscribed (the SDK's server keeps no history).
        page: serve the page (``--view``).
        foxglove: ``--foxglove-port`` with ``--foxglove`` (None: no Foxglove server).
        response: :func:`view_response`'s message (None: none), sent once; a page that
            comes later gets it first.

    Raises:
        UsageError: a port is taken or cannot be bound (one line naming the fix).
    """

    def __init__(
        self,
        port: int,
        *,
        title: str,
        bands: dict[str, Any],
        speed: float | None,
        replay: bool,
        page: bool = True,
        foxglove: int | None = None,
        response: dict[str, Any] | None = None,
    ) -> None:
        from twotank_validation.view import Pacer, ViewServer  # noqa: PLC0415
        from twotank_validation.view.sinks import ReportSink, Tee  # noqa: PLC0415

        pace = math.inf if speed is None else speed
        self.server: ViewServer | None = None
        if page:
            try:
                self.server = ViewServer(port, title=title, models=bands, speed=pace)
            except OSError as err:
                raise UsageError(
                    f"--view-port {port}: cannot listen on 127.0.0.1:{port} ({err.strerror}): "
                    "choose another port, or 0 for any free one"
                ) from err
        self.foxglove = None if foxglove is None else _foxglove_view(foxglove, bands)
        sinks: list[ReportSink] = [s for s in (self.server, self.foxglove) if s is not None]
        self.sink: ReportSink = sinks[0] if len(sinks) == 1 else Tee(sinks)
        self.pacer = Pacer(pace) if replay else None
        self.replay = replay
        if response is not None and self.server is not None:
            self.server.publish(response)

    def __enter__(self) -> ViewRun:
        if self.server is not None:
            self.server.start()
            print(f"view: {self.server.url}", file=sys.stderr, flush=True)
        if self.foxglove is not None:
            print(f"foxglove: {self.foxglove.url}", file=sys.stderr, flush=True)
            if self.replay:
                print(
                    "foxglove: the replay starts when a client has subscribed (connect "
                    f"Foxglove or Lichtblick to {self.foxglove.url}; Ctrl-C to stop)",
                    file=sys.stderr,
                    flush=True,
                )
                self.foxglove.wait_for_client()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self.server is not None:
            self.server.close()
        if self.foxglove is not None:
            self.foxglove.close()

    def report(self, rep: WindowReport, start_ns: int = 0) -> None:
        """The listener: pace (a replay), then push the report to the pages and Foxglove."""
        if self.pacer is not None:
            self.pacer(rep)
        self.sink.publish_report(rep, start_ns)

    def transition(self, tr: Transition) -> None:
        """The listener of the supervisor's mode changes: the page's mode, as it happens."""
        from twotank_validation.view.messages import mode_message  # noqa: PLC0415

        self.sink.publish(mode_message(tr.to_mode.value, tr.time_s, tr.reason))

    def hold(self, text: str) -> None:
        """Say the run ended (``text``) and keep the servers up until SIGINT or SIGTERM."""
        where = []
        if self.server is not None:
            self.server.end(text)
            where.append(f"the page stays at {self.server.url}")
        if self.foxglove is not None:
            where.append(f"the Foxglove server stays at {self.foxglove.url}")
        print(f"view: {text}; {' and '.join(where)} until Ctrl-C", file=sys.stderr, flush=True)
        done = threading.Event()
        old: dict[signal.Signals, Any] = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                old[sig] = signal.signal(sig, lambda _n, _f: done.set())
        try:
            while not done.wait(0.2):
                pass
        finally:
            for signum, handler in old.items():
                signal.signal(signum, handler)


def live_view(
    args: argparse.Namespace, models: Sequence[str], first: Callable[[WindowReport], None]
) -> tuple[ViewRun | None, Callable[[WindowReport], None]]:
    """``live --view``'s and ``--foxglove``'s view (None without either) and the listener.

    The listener calls ``first`` (what ``live`` prints), then pushes the report to the view.
    With ``--supervisor`` the page starts with the supervisor's initial mode; its changes go
    to :meth:`ViewRun.transition` (``run_live(on_transition=...)``).
    """
    response = view_response(args, models, page=args.view)
    if not (args.view or args.foxglove):
        return None, first
    view = ViewRun(
        args.view_port,
        title="live",
        bands=model_bands(models),
        speed=1.0,
        replay=False,
        page=args.view,
        foxglove=args.foxglove_port if args.foxglove else None,
        response=response,
    )
    if getattr(args, "supervisor", None) is not None:
        from twotank_validation.view.messages import mode_message  # noqa: PLC0415

        view.sink.publish(mode_message(SupervisorState().mode.value, 0.0))

    def report(rep: WindowReport) -> None:
        first(rep)
        view.report(rep)

    return view, report


def _foxglove_view(port: int, bands: dict[str, Any]) -> Any:
    """The Foxglove server (:class:`~twotank_validation.view.foxglove.FoxgloveView`).

    Raises:
        UsageError: the SDK is missing or cannot listen on the port (one line naming the fix).
    """
    try:
        from twotank_validation.view.foxglove import FoxgloveView  # noqa: PLC0415
    except ImportError as err:
        raise UsageError(
            f"--foxglove needs the Foxglove SDK ({err}): pip install foxglove-sdk "
            "(requirements.txt pins it)"
        ) from err
    try:
        return FoxgloveView(port, models=bands)
    except RuntimeError as err:
        raise UsageError(
            f"--foxglove-port {port}: cannot listen on 127.0.0.1:{port} ({err}): "
            "choose another port, or 0 for any free one"
        ) from err
