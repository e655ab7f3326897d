"""``twotank-validation live``: the fault named on stdout and in the JSON, and interrupts.

Plant, excitation and validator nodes on a simulated clock at Ts = 0.8 s and a 256-sample
period (the paper's 204.8 s period with 8x fewer messages), the default models A and B. The
reference is the fault injected into the plant, a leak of 0.04 (above the default alarm's
stated limit 0.03, docs/detection.md): the answer that names it is
``expected_effect(leak)`` (``leak`` on ``height``); Model A's own defect, invalidated by
design, is the missing coupling (``coupling`` on ``temperature``, docs/diagnosis.md).
"""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
from typing import Any

import pytest

from twotank_validation import cli
from twotank_validation.diagnose.kinds import expected_effect
from twotank_validation.sim.faults import parse_fault

FAST = ["--ts", "0.8", "--period", "256"]
ONSET_S = 900.0
LEAK = f"leak=0.04@{ONSET_S:g}"
WANT_B = tuple(str(x) for x in expected_effect(parse_fault(LEAK)))
WANT_A = ("coupling", "temperature")
ANSWER = re.compile(
    r"^\[\s*(?P<t>[\d.]+) s\] model (?P<model>\w+): fault named: (?P<kind>\w+) on "
    r"(?P<channel>\w+) .*probability (?P<p>[\d.]+)"
)


def test_live_names_the_fault_of_every_alarm_on_stdout_in_simulated_time(capfd) -> None:
    """Before: only Model A's answer, and only in ROS log lines stamped with the wall clock."""
    code = cli.main(["live", *FAST, "--duration", "1450", "--fault", LEAK])
    captured = capfd.readouterr()
    assert code == 0, captured.err
    lines = captured.out.splitlines()
    answers = [m.groupdict() for m in map(ANSWER.match, lines) if m]
    by_model = {a["model"]: a for a in answers}  # the last answer of each model
    assert set(by_model) == {"A", "B"}, lines[-8:]
    assert (by_model["B"]["kind"], by_model["B"]["channel"]) == WANT_B
    assert (by_model["A"]["kind"], by_model["A"]["channel"]) == WANT_A
    for a in answers:  # stamped in simulated seconds, inside the run
        assert 0.0 < float(a["t"]) <= 1450.0
        assert 0.0 <= float(a["p"]) <= 1.0
    b = [a for a in answers if a["model"] == "B"]
    assert all(float(a["t"]) > ONSET_S for a in b)
    # the answer is printed right after the report of the window that started it
    for i, line in enumerate(lines):
        m = ANSWER.match(line)
        if m:
            prev = lines[i - 1]
            assert f"model {m['model']}:" in prev
            assert f"{float(m['t']):8.1f}] s" in prev, (prev, line)
    # the closing summary names both faults; the ROS log does not repeat them on stderr
    tail = "\n".join(lines[lines.index(next(x for x in lines if x.startswith("summary:"))) :])
    assert "model B:" in tail
    assert "fault named: leak on height" in tail
    assert "fault named: coupling on temperature" in tail
    assert "most likely" not in captured.err


def _start(args: list[str]) -> tuple[subprocess.Popen[str], queue.Queue[str | None]]:
    """Start ``live`` in a subprocess; its stdout lines arrive on the queue (None at EOF)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "twotank_validation.cli", "live", *FAST, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"},
    )
    lines: queue.Queue[str | None] = queue.Queue()

    def pump() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return proc, lines


def _wait_for(lines: queue.Queue[str | None], seen: list[str], cond: Any, timeout_s: float) -> None:
    """Collect lines into ``seen`` until ``cond(line)`` holds for one (polling, no sleep)."""
    while True:
        line = lines.get(timeout=timeout_s)
        assert line is not None, f"live ended before the expected line; got {seen[-3:]}"
        seen.append(line)
        if cond(line):
            return


def _finish(
    proc: subprocess.Popen[str], lines: queue.Queue[str | None], seen: list[str]
) -> tuple[int, str]:
    code = proc.wait(timeout=120)
    while (line := lines.get(timeout=30)) is not None:
        seen.append(line)
    assert proc.stderr is not None
    return code, proc.stderr.read()


def test_sigint_ends_live_with_one_line_a_summary_and_valid_json() -> None:
    """Before: a KeyboardInterrupt traceback and no summary. The fault named before the
    interrupt is in the JSON (each report's answer in force and the closing summary)."""
    proc, lines = _start(["--json", "--duration", "20000", "--fault", LEAK])
    seen: list[str] = []

    def b_named(line: str) -> bool:
        doc = json.loads(line)
        return doc.get("model") == "B" and doc.get("diagnosis") is not None

    try:
        _wait_for(lines, seen, b_named, 120)
        proc.send_signal(signal.SIGINT)
        code, err = _finish(proc, lines, seen)
    finally:
        proc.kill()
    assert code == 128 + signal.SIGINT, err
    assert "Traceback" not in err
    assert "SIGINT: stopping" in err
    docs = [json.loads(line) for line in seen]  # every line is one complete JSON object
    reports = [d for d in docs if "model" in d]
    summary = docs[-1]["summary"]
    assert summary["interrupted"] is True
    assert summary["signal"] == "SIGINT"
    assert summary["simulated_s"] < 20000
    assert reports[-1]["end"] <= summary["simulated_s"]
    for name in ("A", "B"):  # the summary counts the windows the lines show
        mine = [r for r in reports if r["model"] == name]
        entry = summary["models"][name]
        assert entry["windows"] == len(mine)
        assert entry["judged"] == sum(r["judged"] for r in mine)
        assert entry["alarm"] == mine[-1]["alarm"]
    for name, want in (("B", WANT_B), ("A", WANT_A)):
        fault = summary["models"][name]["alarms"][-1]["fault"]
        assert (fault["kind"], fault["channel"]) == want
        assert 0.0 <= fault["probability"] <= 1.0
        assert fault["window_end"] <= summary["simulated_s"]
    first_b = next(r for r in reports if r["model"] == "B" and r["diagnosis"] is not None)
    assert first_b["diagnosis"]["window_end"] == first_b["end"]  # rides on its own window
    assert first_b["diagnosis"]["window_end"] > ONSET_S


@pytest.mark.parametrize("sig", [signal.SIGTERM])
def test_sigterm_ends_live_with_a_summary(sig: signal.Signals) -> None:
    proc, lines = _start(["--duration", "20000"])
    seen: list[str] = []
    try:
        _wait_for(lines, seen, lambda line: "model B:" in line, 120)
        proc.send_signal(sig)
        code, err = _finish(proc, lines, seen)
    finally:
        proc.kill()
    assert code == 128 + sig, err
    assert "Traceback" not in err
    assert any(line.startswith("summary: ") and sig.name in line for line in seen), seen[-4:]
    assert any("model B:" in line and "window(s)" in line for line in seen)
