"""An interrupt keeps what was judged (issue 27, item 5).

Each command runs as a subprocess; the test waits for its first result (a streamed row on
stdout, the timing note on stderr, the first JSON of a fleet: polled, never a blind sleep),
sends SIGINT or SIGTERM, and checks: exit 130 or 143, one line about it and no traceback on
stderr, the JSON valid with ``"interrupted": true`` holding every window printed, the figures
of what was judged, a fleet's summary of what finished and no worker process left behind.
"""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from twotank_validation import cli
from twotank_validation.errors import ExitCode

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
ROW = re.compile(r"^\s*(\d+\.\d)-\s*(\d+\.\d)\s+(\S+)\s")  # "  204.8-  614.3  B  ..."
CODE = {signal.SIGINT: ExitCode.INTERRUPTED, signal.SIGTERM: ExitCode.TERMINATED}


@pytest.fixture(scope="module")
def leak_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The shipped leak scenario (4000 s at 0.1 s), as the issue makes it."""
    bag = tmp_path_factory.mktemp("interrupts") / "leak_bag"
    assert cli.main(["simulate", "--scenario", "leak", "--out", str(bag), "--quiet"]) == 0
    return bag


class Run:
    """A command in its own process group, its stdout and stderr read as they come."""

    def __init__(self, args: list[str], cwd: Path) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "twotank_validation.cli", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=ENV,
            cwd=cwd,
            start_new_session=True,
        )
        self.out: list[str] = []
        self.err: list[str] = []
        self._partial = {1: b"", 2: b""}

    def _pump(self, timeout: float) -> None:
        assert self.proc.stdout is not None
        assert self.proc.stderr is not None
        streams = {self.proc.stdout.fileno(): 1, self.proc.stderr.fileno(): 2}
        ready, _, _ = select.select(list(streams), [], [], timeout)
        for fd in ready:
            data = os.read(fd, 65536)
            which = streams[fd]
            lines = (self._partial[which] + data).split(b"\n")
            self._partial[which] = lines.pop()
            (self.out if which == 1 else self.err).extend(x.decode() for x in lines)

    def wait_for(self, found, timeout: float = 120.0) -> None:
        """Read until ``found()`` is true (polling), or fail."""
        end = time.monotonic() + timeout
        while not found():
            assert self.proc.poll() is None, ("ended before the signal", self.out, self.err)
            assert time.monotonic() < end, ("nothing came", self.out, self.err)
            self._pump(0.05)

    def finish(self, timeout: float = 120.0) -> int:
        """Read to the end; the exit code."""
        end = time.monotonic() + timeout
        while self.proc.poll() is None and time.monotonic() < end:
            self._pump(0.05)
        code = self.proc.wait(timeout=5)
        for _ in range(100):  # what is left in the pipes
            before = len(self.out) + len(self.err)
            self._pump(0.0)
            if len(self.out) + len(self.err) == before:
                break
        self.out += [self._partial[1].decode()] if self._partial[1] else []
        self.err += [self._partial[2].decode()] if self._partial[2] else []
        return code


def _alive_in_group(pgid: int, wait_s: float = 10.0) -> list[str]:
    """The processes of the group still running (not zombies), after up to ``wait_s``."""
    end = time.monotonic() + wait_s
    while True:
        alive = []
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:  # gone meanwhile
                continue
            if int(fields[2]) == pgid and fields[0] != "Z":  # state, ppid, pgrp
                alive.append(stat.parent.name)
        if not alive or time.monotonic() > end:
            return alive
        time.sleep(0.1)


def _rows(lines: list[str]) -> list[tuple[float, float, str]]:
    return [(float(m[1]), float(m[2]), m[3]) for m in map(ROW.match, lines) if m]


def _check_one_line_no_traceback(run: Run, sig: signal.Signals) -> None:
    text = "\n".join(run.err)
    assert "Traceback" not in text, text
    told = [line for line in run.err if "interrupted" in line]
    assert len(told) == 1, run.err
    assert sig.name in told[0]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_validate_keeps_the_windows_printed(leak_bag, tmp_path, sig) -> None:
    run = Run(["validate", str(leak_bag), "--json", "out.json", "--report", "figs"], tmp_path)
    run.wait_for(lambda: bool(_rows(run.out)))  # the first row, streamed as it was judged
    run.proc.send_signal(sig)
    assert run.finish() == CODE[sig]
    _check_one_line_no_traceback(run, sig)
    printed = _rows(run.out)
    assert printed
    doc = json.loads((tmp_path / "out.json").read_text())
    assert doc["interrupted"] is True
    assert doc["complete"] is False
    kept = {
        (round(w["start"], 1), round(w["end"], 1), name)
        for name, entry in doc["models"].items()
        for w in entry["windows"]
    }
    assert set(printed) <= kept  # every window printed is in the JSON
    assert len(printed) == len(kept)  # and the table holds every window kept
    assert (tmp_path / "figs" / "alarm_timeline.png").stat().st_size > 0
    assert any(line.startswith("model B: ") for line in run.out)  # the closing lines


def test_diagnose_keeps_what_was_judged(leak_bag, tmp_path) -> None:
    run = Run(["diagnose", str(leak_bag), "--model", "B", "--json", "d.json"], tmp_path)
    run.wait_for(lambda: any("judged window(s)" in line for line in run.out))  # diagnosing
    run.proc.send_signal(signal.SIGINT)
    assert run.finish() == ExitCode.INTERRUPTED
    _check_one_line_no_traceback(run, signal.SIGINT)
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["interrupted"] is True
    assert doc["model"] == "B"
    assert set(doc["replay"]["models"]) == {"B"}


def test_calibrate_keeps_what_was_judged(leak_bag, tmp_path) -> None:
    run = Run(["calibrate", str(leak_bag), "--model", "A", "--json", "c.json"], tmp_path)
    run.wait_for(lambda: any("judged window(s)" in line for line in run.out))  # calibrating
    run.proc.send_signal(signal.SIGTERM)
    assert run.finish() == ExitCode.TERMINATED
    _check_one_line_no_traceback(run, signal.SIGTERM)
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["interrupted"] is True
    assert set(doc["replay"]["models"]) == {"A"}


def test_a_fleet_keeps_what_finished_and_stops_its_workers(leak_bag, tmp_path) -> None:
    archive = tmp_path / "archive"
    for k in range(4):
        shutil.copytree(leak_bag, archive / f"run{k}")
    out = tmp_path / "results"
    args = ["validate", str(archive), "--out", str(out), "--workers", "1", "--model", "B"]
    args.append("--no-diagnosis")
    run = Run(args, tmp_path)
    run.wait_for(lambda: any(out.glob("*.json")))  # the first recording finished
    os.killpg(run.proc.pid, signal.SIGINT)  # Ctrl-C: the whole foreground process group
    assert run.finish() == ExitCode.INTERRUPTED
    _check_one_line_no_traceback(run, signal.SIGINT)
    assert _alive_in_group(run.proc.pid) == []  # no worker left behind
    table = pd.read_csv(out / "summary.csv")
    assert len(table) == 4
    finished = table[table["status"] == "complete"]
    assert len(finished) >= 1
    assert len(finished) < 4
    assert set(table["status"]) <= {"complete", "interrupted", "not run"}
    assert sorted(p.name for p in out.glob("*.json")) == sorted(finished["json"])
    assert (out / "fleet.png").stat().st_size > 0
