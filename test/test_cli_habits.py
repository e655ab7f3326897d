"""The command line's habits (issue 27, item 10): exit codes as documented, help that says
each default once and every exit code, a subcommand's own usage on a typo with the option
it resembles, no prefix matching, ``--version``, a closed pipe without a traceback, and
progress on a terminal only."""

from __future__ import annotations

import dataclasses
import fcntl
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

from twotank_validation import __version__, cli
from twotank_validation.bags import write_scenario_bag
from twotank_validation.errors import ExitCode
from twotank_validation.sim import scenario as sc

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
COMMANDS = ["demo", "live", "simulate", "record", "validate", "diagnose", "calibrate"]


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six periods of the nominal rig at ts 0.8 s, period 256: 5,760 messages."""
    base = sc.load_scenario("nominal")
    short = dataclasses.replace(base, ts_s=0.8, period_samples=256, duration_s=6 * 0.8 * 256)
    path = tmp_path_factory.mktemp("habits") / "good"
    write_scenario_bag(short, path, progress=False)
    return path


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = cli.main(args)
    except SystemExit as stop:  # argparse's own exits (--help, --version, usage errors)
        code = int(stop.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_an_empty_file_is_unreadable_with_the_documented_code(tmp_path, capsys) -> None:
    empty = tmp_path / "x.mcap"
    empty.write_bytes(b"")
    code, _, err = _run(["validate", str(empty), "--quiet"], capsys)
    # docs/cli.md: 2 = nothing could be done (not a bag, unreadable); 3 = incomplete
    assert code == ExitCode.ERROR == 2
    assert "empty (0 bytes)" in err
    assert "--topic" not in err  # no advice to map streams
    assert "record the topics" not in err
    assert "Traceback" not in err


def test_nothing_judged_does_not_say_judged(bag, capsys) -> None:
    code, _, err = _run(["validate", str(bag), "--quiet", "--ts", "0.3"], capsys)
    assert code == ExitCode.NOT_JUDGED
    assert "judged with" not in err
    errors = [line for line in err.splitlines() if line.startswith("ERROR:")]
    assert errors
    assert all("could be judged" in line for line in errors)
    assert "note: the windows were formed with sample period 0.3 s (option)" in err


@pytest.mark.parametrize("command", COMMANDS)
def test_help_says_each_default_once_and_every_exit_code(command, capsys) -> None:
    code, out, _ = _run([command, "--help"], capsys)
    assert code == 0
    text = " ".join(out.split())
    assert "(default: None)" not in text
    assert "(default: False)" not in text
    assert not re.search(r"default[^()]*\) \(default:", text)  # two defaults in a row
    for exit_code in ExitCode:  # the enum is the reference: every code is listed
        assert re.search(rf"\b{int(exit_code)} [A-Za-z]", text.split("exit codes:")[1]), exit_code


def test_the_documented_exit_codes_are_the_enums() -> None:
    table = (ROOT / "docs" / "cli.md").read_text().split("## Exit codes")[1].split("\n## ")[0]
    listed = {int(m) for m in re.findall(r"^\| (\d+) \|", table, flags=re.MULTILINE)}
    assert listed == {int(c) for c in ExitCode}


def test_a_misspelt_option_gets_the_subcommands_usage_and_a_suggestion(bag, capsys) -> None:
    code, _, err = _run(["validate", str(bag), "--modle", "B"], capsys)
    assert code == 2
    assert err.startswith("usage: twotank-validation validate ")
    assert "unrecognized arguments: --modle" in err
    assert "did you mean --model?" in err


@pytest.mark.parametrize("command", ["validate", "diagnose", "calibrate"])
def test_a_prefix_of_an_option_is_not_accepted(bag, command, capsys) -> None:
    code, _, err = _run([command, str(bag), "--mod", "B"], capsys)
    assert code == 2
    assert "--mod" in err


def test_version(capsys) -> None:
    code, out, _ = _run(["--version"], capsys)
    assert code == 0
    assert out.strip() == f"twotank-validation {__version__}"


def test_a_closed_pipe_ends_any_command_quietly(tmp_path) -> None:
    """`live | head -3`: main() ends a command whose reader went away (here a stand-in)."""
    script = (
        "import sys\n"
        "from twotank_validation import cli\n"
        "def chatty(args):\n"
        "    for k in range(10**6):\n"
        "        print(f'line {k}', flush=True)\n"
        "    return 0\n"
        "cli._cmd_demo = chatty\n"
        "sys.exit(cli.main(['demo']))\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV
    )
    assert proc.stdout is not None
    assert proc.stderr is not None
    assert proc.stdout.readline() == b"line 0\n"
    proc.stdout.close()  # the reader goes away (head -1)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == ExitCode.BROKEN_PIPE == 141
    assert err == ""  # no traceback, no "Exception ignored" at the exit flush


def _stderr_of(cmd: list[str], *, terminal: bool, cwd: Path) -> tuple[int, str]:
    """The command's exit code and its stderr, on a pseudo-terminal or a pipe."""
    if not terminal:
        proc = subprocess.run(cmd, check=False, capture_output=True, env=ENV, cwd=cwd, timeout=120)
        return proc.returncode, proc.stderr.decode(errors="replace")
    master, slave = pty.openpty()
    # a terminal of 80 columns (a new pseudo-terminal has 0: a bar would have no room)
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    proc2 = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=slave, env=ENV, cwd=cwd, close_fds=True
    )
    os.close(slave)
    chunks = []
    while True:
        ready, _, _ = select.select([master], [], [], 120)
        if not ready:
            break
        try:
            data = os.read(master, 65536)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    return proc2.wait(timeout=120), b"".join(chunks).decode(errors="replace")


BAR = re.compile(r"\d+%\|")  # tqdm's bar: "42%|####"


@pytest.mark.parametrize("terminal", [True, False], ids=["terminal", "pipe"])
def test_progress_shows_on_a_terminal_only(bag, tmp_path, terminal) -> None:
    exe = [sys.executable, "-m", "twotank_validation.cli"]
    quick = ["--model", "B", "--no-diagnosis"]
    long_sim = tmp_path / "long.yaml"
    long_sim.write_text("name: long\nduration_s: 2100\n")  # 21,000 samples at 0.1 s
    runs = {
        "simulate": [*exe, "simulate", "--scenario", str(long_sim), "--out", "sim_bag"],
        "validate": [*exe, "validate", str(bag), *quick],
        "fleet": [*exe, "validate", str(bag), *quick, "--serial", "--out", "fleet_out"],
    }
    for name, cmd in runs.items():
        code, err = _stderr_of(cmd, terminal=terminal, cwd=tmp_path)
        assert code == 0, (name, err)
        assert bool(BAR.search(err)) is terminal, (name, err)
        assert "Traceback" not in err
