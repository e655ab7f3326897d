"""The reports over the Foxglove WebSocket protocol, and the layout files (docs/view.md).

The reference is the JSON the same run writes (``validate --json``'s windows) and the run's
own reports: a client of the protocol (``websockets``; subprotocol ``foxglove.sdk.v1``:
serverInfo and advertise in, subscribe out, binary messageData in) receives each window's
report, whose every field equals the JSON entry's, stamped with the window's end; the per-bin
minimum ‖W‖ equals the report's. The server is probed for listening on 127.0.0.1 only (the
kernel's socket table). The layouts are parsed and every channel and field they name is
checked against the advertised channels' schemas (Foxglove) and the ROS message definition
(PlotJuggler).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import re
import signal
import struct
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from websockets.sync.client import ClientConnection, connect

from twotank_validation import cli
from twotank_validation.bags import write_scenario_bag
from twotank_validation.online import WindowReport
from twotank_validation.online.livediag import LiveDiagnosis
from twotank_validation.online.window import MonitorConfig
from twotank_validation.sim import scenario as sc
from twotank_validation.usecases import ValidateJob
from twotank_validation.usecases.reading import ReadSettings
from twotank_validation.view.foxglove import SUBPROTOCOL, FoxgloveView
from twotank_validation.view.sinks import Tee

ROOT = Path(__file__).resolve().parents[1]
FAST = MonitorConfig(ts_s=0.8, period_samples=256)
MESSAGE_DATA = 0x01


@pytest.fixture(scope="module")
def leak_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """8 periods of the rig at Ts 0.8 s, period 256, a leak from 1000 s."""
    base = sc.load_scenario("leak")
    s = dataclasses.replace(
        base, ts_s=0.8, period_samples=256, duration_s=8 * 204.8, faults=("leak=0.04@1000",)
    )
    return write_scenario_bag(s, tmp_path_factory.mktemp("fox") / "leak", storage="mcap")


class Client:
    """A minimal client of the protocol: the channels advertised, the messages received."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.info = json.loads(self.ws.recv(timeout=5))
        self.channels: dict[int, dict[str, Any]] = {}
        self.subs: dict[int, dict[str, Any]] = {}

    def advertised(self, n: int) -> dict[str, dict[str, Any]]:
        """Read advertise messages until ``n`` channels are known; topic -> channel."""
        while len(self.channels) < n:
            msg = json.loads(self.ws.recv(timeout=5))
            if msg["op"] == "advertise":
                self.channels.update({c["id"]: c for c in msg["channels"]})
        return {c["topic"]: c for c in self.channels.values()}

    def subscribe_all(self) -> None:
        """One subscribe message for every advertised channel."""
        self.subs = dict(enumerate(self.channels.values(), start=1))
        subscriptions = [{"id": i, "channelId": c["id"]} for i, c in self.subs.items()]
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def messages(self, quiet_s: float = 1.0) -> Iterator[tuple[str, int, dict[str, Any]]]:
        """(topic, timestamp ns, payload) of each messageData until none came for quiet_s."""
        while True:
            try:
                frame = self.ws.recv(timeout=quiet_s)
            except TimeoutError:
                return
            if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                sub, stamp = struct.unpack_from("<IQ", frame, 1)
                yield self.subs[sub]["topic"], stamp, json.loads(frame[13:])


def _connect(url: str) -> ClientConnection:
    """A connection speaking the SDK's subprotocol (messages kept unread without limit)."""
    return connect(url, subprotocols=[SUBPROTOCOL], max_queue=None)


def _listening(port: int) -> list[str]:
    """The local addresses of the sockets listening on ``port`` (the kernel's tables)."""
    out = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            addr, hexport = local.split(":")
            if state == "0A" and int(hexport, 16) == port:  # 0A: LISTEN
                out.append(addr)
    return out


def test_a_client_receives_the_replay_s_reports_equal_to_the_json(
    leak_bag: Path, tmp_path: Path
) -> None:
    job = ValidateJob(
        str(leak_bag),
        ReadSettings(monitor=FAST),
        models=("A", "B"),
        diagnosis=True,
        json_path=str(tmp_path / "v.json"),
    )
    reports: list[WindowReport] = []
    with contextlib.ExitStack() as stack:
        fox = stack.enter_context(FoxgloveView(0, models=("A", "B")))
        # 127.0.0.1 and nothing else (0100007F: 127.0.0.1 in the kernel's byte order)
        assert _listening(fox.port) == ["0100007F"]
        client = Client(stack.enter_context(_connect(fox.url)))
        assert client.info["op"] == "serverInfo"
        assert client.ws.subprotocol == SUBPROTOCOL
        topics = client.advertised(6)
        assert set(topics) == {
            f"/validation/{m}/{k}" for m in "AB" for k in ("report", "w_min", "diagnosis")
        }
        assert all(c["encoding"] == "json" for c in topics.values())
        client.subscribe_all()
        deadline = time.monotonic() + 5
        while fox.subscriptions < 6 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert fox.subscriptions == 6

        def listen(rep: WindowReport, start_ns: int) -> None:
            reports.append(rep)
            fox.publish_report(rep, start_ns)

        assert job.run(on_report=listen).code == 0
        got: dict[str, list[tuple[int, dict[str, Any]]]] = {}
        for t, stamp, payload in client.messages():
            got.setdefault(t, []).append((stamp, payload))

    doc = json.loads((tmp_path / "v.json").read_text())
    for model, entry in doc["models"].items():
        windows = entry["windows"]
        received = got[f"/validation/{model}/report"]
        mine = [r for r in reports if r.model == model]
        assert len(received) == len(windows) == len(mine) >= 8
        for (stamp, msg), win, rep in zip(received, windows, mine, strict=True):
            assert {k: msg[k] for k in win} == win  # every field of the JSON's entry, exact
            assert msg["model"] == model
            assert stamp == rep.end_ns  # the window's end in the recording's time
        judged = [r for r in mine if r.judged]
        spectra = got[f"/validation/{model}/w_min"]
        assert len(spectra) == len(judged)
        for (stamp, msg), rep in zip(spectra, judged, strict=True):
            keep = rep.freqs_hz > 0
            assert stamp == rep.end_ns
            assert msg["freqs_hz"] == rep.freqs_hz[keep].tolist()
            assert msg["w_min"] == rep.w_min[keep].tolist()
    # the leak raises B's alarm and a diagnosis: each new answer, as the window entry has it
    diagnoses = got.get("/validation/B/diagnosis", [])
    answers = {
        (w["diagnosis"]["onset"], w["diagnosis"]["update"]): w["diagnosis"]
        for w in doc["models"]["B"]["windows"]
        if w["diagnosis"] is not None
    }
    assert answers, "the leak should be diagnosed"
    assert [{k: m[k] for k in m if k != "model"} for _, m in diagnoses] == list(answers.values())


def test_attached_diagnoses_go_to_their_channel_through_a_tee_and_modes_do_not() -> None:
    """``view --foxglove``: the view node's messages (diagnosis, mode) through a :class:`Tee`."""
    diag = LiveDiagnosis(
        model="B", kind="leak", channel="height", parameters={"outflow": 0.04}, score=0.9,
        summary="leak on height", onset_ns=1_000_000_000_000, window_end_ns=1_300_000_000_000,
        windows=2, update=1, probability=0.99,
    )  # fmt: skip
    seen: list[dict[str, Any]] = []

    class Page:
        def publish_report(self, rep: WindowReport, start_ns: int = 0) -> None:
            raise AssertionError("no report here")

        def publish(self, message: dict[str, Any]) -> None:
            seen.append(message)

    with FoxgloveView(0, models=("B",)) as fox, _connect(fox.url) as ws:
        client = Client(ws)
        client.advertised(3)
        client.subscribe_all()
        while fox.subscriptions < 3:
            time.sleep(0.01)
        tee = Tee([Page(), fox])
        tee.publish({"type": "mode", "mode": "safe", "time": 1.0, "wall": 0.0})
        tee.publish({"type": "diagnosis", "model": "B", "diagnosis": diag.to_json()})
        got = list(client.messages(quiet_s=0.3))
    assert [m["type"] for m in seen] == ["mode", "diagnosis"]  # the page gets both
    assert got == [
        ("/validation/B/diagnosis", diag.window_end_ns, {"model": "B", **diag.to_json()})
    ]


def test_validate_foxglove_waits_for_a_client_then_serves_the_json_s_windows(
    leak_bag: Path, tmp_path: Path
) -> None:
    """``validate --foxglove``: the command's wiring, its wait for a client and its hold."""
    out = tmp_path / "v.json"
    cmd = [sys.executable, "-m", "twotank_validation.cli", "validate", str(leak_bag), "--ts",
           "0.8", "--period", "256", "--foxglove", "--foxglove-port", "0", "--json", str(out),
           "--quiet"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    got: dict[str, list[dict[str, Any]]] = {}
    try:
        assert proc.stderr is not None
        first = proc.stderr.readline()
        m = re.fullmatch(r"foxglove: (ws://127\.0\.0\.1:\d+)", first.strip())
        assert m, first
        assert "starts when a client has subscribed" in proc.stderr.readline()
        assert not out.exists()  # nothing judged before a client came
        with _connect(m.group(1)) as ws:
            client = Client(ws)
            client.advertised(6)
            client.subscribe_all()
            for line in proc.stderr:  # the replay runs, then holds the server up
                if "Foxglove server stays at" in line:
                    break
            for t, _, payload in client.messages(quiet_s=0.5):
                got.setdefault(t, []).append(payload)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=20)
    assert proc.returncode == 0
    doc = json.loads(out.read_text())
    for model, entry in doc["models"].items():
        received, windows = got[f"/validation/{model}/report"], entry["windows"]
        assert len(received) == len(windows) >= 8
        assert [{k: r[k] for k in w} for r, w in zip(received, windows, strict=True)] == windows


def test_foxglove_options_are_refused_where_they_cannot_work(capsys: Any, leak_bag: Path) -> None:
    assert cli.main(["validate", str(leak_bag), str(leak_bag), "--foxglove"]) == 2
    assert "--foxglove shows one recording" in capsys.readouterr().err
    with FoxgloveView(0) as fox:
        assert fox.port > 0
        with pytest.raises(RuntimeError):
            FoxgloveView(fox.port)
        taken = ["validate", str(leak_bag), "--foxglove", "--foxglove-port", str(fox.port)]
        assert cli.main(taken) == 2
    assert "choose another port" in capsys.readouterr().err


# --------------------------------------------------------------------------- the layouts


def _schema_fields(schema: dict[str, Any]) -> set[str]:
    return set(schema["properties"])


def _foxglove_paths(cfg: dict[str, Any]) -> list[str]:
    """Every message path a panel config names (series, x axis, indicator, raw messages)."""
    out = []
    for panel in cfg.values():
        out += [p["value"] for p in panel.get("paths", [])]
        out += [panel[k] for k in ("path", "topicPath") if k in panel]
        if "xAxisPath" in panel:
            out.append(panel["xAxisPath"]["value"])
    return out


def test_the_foxglove_layout_names_only_advertised_channels_and_schema_fields() -> None:
    layout = json.loads((ROOT / "layouts" / "twotank_foxglove.json").read_text())
    cfg = layout["configById"]
    with FoxgloveView(0, models=("A", "B")) as fox, _connect(fox.url) as ws:
        channels = Client(ws).advertised(6)
    schemas = {t: json.loads(c["schema"]) for t, c in channels.items()}
    named = set()
    for path in _foxglove_paths(cfg):
        if re.fullmatch(r"[0-9.]+", path):
            assert float(path) == 1.0  # the reference line β = 1
            continue
        topic, _, field = path.partition(".")
        assert topic in schemas, path
        named.add(topic)
        if field:
            assert re.sub(r"\[:\]$", "", field) in _schema_fields(schemas[topic]), path
    assert named == {f"/validation/{m}/{k}" for m in "AB" for k in ("report", "w_min", "diagnosis")}
    # every panel is placed in the layout and every leaf is a configured panel
    leaves: set[str] = set()

    def walk(node: Any) -> None:
        if isinstance(node, str):
            leaves.add(node)
        else:
            walk(node["first"])
            walk(node["second"])

    walk(layout["layout"])
    assert leaves == set(cfg)
    assert {k.split("!")[0] for k in cfg} == {
        "Plot",
        "StateTransitions",
        "Indicator",
        "RawMessages",
    }


def test_the_plotjuggler_layout_names_the_validator_s_topics_and_message_fields() -> None:
    root = ET.parse(ROOT / "layouts" / "twotank_plotjuggler.xml").getroot()
    msg = (ROOT / "msg" / "ValidationReport.msg").read_text()
    fields = {
        m.group(2)
        for m in re.finditer(r"^\s*([\w/]+(?:\[\])?)\s+(\w+)\s*(?:#|$)", msg, re.MULTILINE)
    }
    assert {"beta", "beta_total", "alarm_level"} <= fields
    plugin = root.find("./Plugins/plugin[@ID='ROS2 Topic Subscriber']")
    assert plugin is not None
    topics = plugin.find("selected_topics").get("value").split(";")  # type: ignore[union-attr]
    # the validator node's topics (validation/M/report, relative: /validation/M/report)
    node = (ROOT / "twotank_validation" / "ros" / "validator_node.py").read_text()
    assert 'f"validation/{m.name}/report"' in node
    assert topics == ["/validation/A/report", "/validation/B/report"]
    curves = [c.get("name") for c in root.iter("curve")]
    assert curves
    for name in curves:
        topic, _, field = name.rpartition("/")  # type: ignore[union-attr]
        assert topic in topics, name
        assert field in fields, name
    assert {n.rpartition("/")[2] for n in curves} >= {"beta"}  # type: ignore[union-attr]
