"""Many recordings in one command (twotank_validation.fleet): summary, exit codes, Dask.

References: each recording validated alone by the single-recording command (its JSON, exit
code and error text), the injected fault's time, the undamaged bag the damaged one was cut
from, and the serial in-process run for every Dask run (byte for byte).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from twotank_validation import cli, fleet
from twotank_validation.bags import write_scenario_bag
from twotank_validation.bags.writer import BagWriter, fluid_pressure
from twotank_validation.errors import ExitCode
from twotank_validation.sim import scenario as sc
from twotank_validation.usecases import Outcome, Status

ROOT = Path(__file__).resolve().parent.parent
FAST_ARGS = ["--ts", "0.8", "--period", "256", "--quiet"]
PERIOD_S = 0.8 * 256
LEAK_AT_S = 700.0
STATUS_OF_CODE = {0: "complete", 3: "incomplete", 4: "not judged", 2: "unreadable"}


def fast_scenario(name: str = "nominal", periods: float = 6, **changes) -> sc.Scenario:
    base = sc.load_scenario(name)
    return dataclasses.replace(
        base, ts_s=0.8, period_samples=256, duration_s=periods * PERIOD_S, **changes
    )


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    """good, leaky (a leak injected at LEAK_AT_S), cut (good truncated at 70 %), foreign (a
    bag of other topics), short (1.5 periods: no whole window), garbage.mcap (random bytes)
    and notes.txt (not a recording), the bags in a sub-folder of their own."""
    root = tmp_path_factory.mktemp("archive")
    (root / "day1").mkdir()
    write_scenario_bag(fast_scenario(), root / "day1" / "good", progress=False)
    write_scenario_bag(
        fast_scenario("leak", periods=8, faults=(f"leak=0.04@{LEAK_AT_S:g}",)),
        root / "leaky",
        progress=False,
    )
    shutil.copytree(root / "day1" / "good", root / "cut")
    data = next((root / "cut").glob("*.mcap"))
    raw = data.read_bytes()
    data.write_bytes(raw[: int(len(raw) * 0.7)])
    with BagWriter(root / "foreign") as bag:
        bag.add_topic("/other/pressure", "sensor_msgs/msg/FluidPressure")
        for k in range(40):
            bag.write("/other/pressure", k * 10**8, fluid_pressure(k * 10**8, 0.5))
    write_scenario_bag(fast_scenario(periods=1.5), root / "short", progress=False)
    (root / "garbage.mcap").write_bytes(bytes(range(256)) * 12)
    (root / "notes.txt").write_text("lab notes, not a recording")
    return root


def recordings(root: Path) -> list[Path]:
    return [
        root / "cut",
        root / "day1" / "good",
        root / "foreign",
        root / "garbage.mcap",
        root / "leaky",
        root / "short",
    ]


def alone(path: Path, tmp: Path, capsys, *extra: str) -> tuple[int, dict | None, str]:
    """The single-recording command's exit code, JSON (None if it wrote none) and stderr."""
    out = tmp / f"alone_{path.name}.json"
    capsys.readouterr()
    code = cli.main(["validate", str(path), "--json", str(out), *FAST_ARGS, *extra])
    err = capsys.readouterr().err
    return code, (json.loads(out.read_text()) if out.exists() else None), err


def run_fleet(tmp: Path, name: str, paths: list[str], *extra: str) -> tuple[int, Path]:
    out = tmp / name
    code = cli.main(["validate", *paths, "--out", str(out), *FAST_ARGS, *extra])
    return code, out


@pytest.fixture(scope="module")
def serial(archive, tmp_path_factory) -> tuple[int, Path]:
    """The archive directory validated in this process (the reference), no live diagnosis."""
    tmp = tmp_path_factory.mktemp("serial")
    return run_fleet(tmp, "out", [str(archive)], "--serial", "--no-diagnosis")


def files(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}


def test_directory_summary_matches_each_recording_alone(archive, serial, tmp_path, capsys):
    code, out = serial
    table = pd.read_csv(out / "summary.csv", keep_default_na=False, na_values=[""])
    rows = {r["recording"]: r for r in table.to_dict("records")}
    codes = {}
    for path in recordings(archive):
        single, doc, err = alone(path, tmp_path, capsys, "--no-diagnosis")
        codes[path.name] = single
        row = rows[str(path)]
        assert row["status"] == STATUS_OF_CODE[single], path
        assert row["code"] == single
        if doc is None:  # unreadable: the same error text, nothing written
            assert single == cli.EXIT_ERROR
            assert row["problem"] in err
            assert row["json"] != row["json"]  # NaN: no file
            continue
        # the fleet's JSON is the one the recording gets alone, whole
        stem = str(row["json"])
        assert json.loads((out / stem).read_text()) == doc
        for m in ("A", "B"):
            e = doc["models"][m]
            assert row[f"{m} judged"] == e["judged"]
            assert row[f"{m} not judged"] == e["not_judged"]
            for col, key in ((f"{m} beta_max", "beta_max"), (f"{m} first_alarm_s", "first_alarm")):
                assert (row[col] != row[col]) if e[key] is None else row[col] == e[key]
    assert codes == {
        "cut": 3,
        "good": 0,
        "foreign": 3,
        "garbage.mcap": 2,
        "leaky": 0,
        "short": 4,
    }
    # the skipped file is listed, not judged
    assert rows[str(archive / "notes.txt")]["status"] == "skipped"
    # an unreadable recording is the most severe: 5
    assert code == fleet.EXIT_UNREADABLE
    # the injected leak raises model B's alarm after it, within three periods
    leak = rows[str(archive / "leaky")]
    assert LEAK_AT_S <= leak["B first_alarm_s"] <= LEAK_AT_S + 3 * PERIOD_S
    assert (
        rows[str(archive / "day1" / "good")]["B first_alarm_s"]
        != rows[str(archive / "day1" / "good")]["B first_alarm_s"]
    )  # NaN: no alarm on the nominal bag
    # nothing lost: the damaged bag's windows are the good bag's windows before the damage
    cut = json.loads((out / "cut.json").read_text())["models"]["B"]["windows"]
    good = json.loads((out / "day1__good.json").read_text())["models"]["B"]["windows"]
    assert 0 < len(cut) < len(good)
    assert [w["beta"] for w in cut] == [w["beta"] for w in good[: len(cut)]]
    # recordings with an alarm come first, in the table as in the figure
    alarmed = [
        any(r[f"{m} first_alarm_s"] == r[f"{m} first_alarm_s"] for m in "AB")
        for r in table.to_dict("records")
    ]
    assert alarmed == sorted(alarmed, reverse=True)
    assert (out / "fleet.png").stat().st_size > 10_000


@pytest.mark.parametrize(
    ("names", "expected"),
    [
        (["leaky"], 0),
        (["leaky", "short"], cli.EXIT_NOT_JUDGED),
        (["short", "cut"], cli.EXIT_INCOMPLETE),
        (["cut", "garbage.mcap"], fleet.EXIT_UNREADABLE),
        (["short"], cli.EXIT_NOT_JUDGED),
    ],
)
def test_exit_code_is_the_most_severe_recordings(archive, tmp_path, names, expected):
    """0 only when all were read completely and judged; nothing judged is never 0."""
    paths = [str(archive / n) for n in names]
    code, out = run_fleet(tmp_path, "out", paths, "--serial", "--no-diagnosis")
    assert code == expected
    table = pd.read_csv(out / "summary.csv")
    assert sorted(table["recording"]) == sorted(paths)


def test_dask_local_cluster_equals_the_serial_run_byte_for_byte(archive, serial, tmp_path):
    code, out = run_fleet(tmp_path, "dask", [str(archive)], "--workers", "2", "--no-diagnosis")
    assert code == serial[0]
    assert files(out) == files(serial[1])  # every JSON, summary.csv and fleet.png


def temporary_tls(tmp: Path) -> list[str]:
    """A self-signed certificate and its key (distributed's ``Security.temporary()``, made
    with cryptography) written as PEM files; returns the options that name them, the same
    for `dask scheduler`, `dask worker` and ``validate``: the certificate is its own CA."""
    from distributed.security import Security  # noqa: PLC0415

    pytest.importorskip("cryptography")  # what Security.temporary() makes them with
    temp = Security.temporary()
    (tmp / "ca.pem").write_text(temp.tls_ca_file)
    (tmp / "cert.pem").write_text(temp.tls_scheduler_cert)
    (tmp / "key.pem").write_text(temp.tls_scheduler_key)
    return [
        *("--tls-ca-file", str(tmp / "ca.pem")),
        *("--tls-cert", str(tmp / "cert.pem")),
        *("--tls-key", str(tmp / "key.pem")),
    ]


@contextlib.contextmanager
def dask_cluster(tmp: Path, tls: list[str] | None = None):
    """A `dask scheduler` and a one-process `dask worker` on 127.0.0.1, shut down after;
    with ``tls`` (:func:`temporary_tls`'s options) both speak TLS only."""
    from distributed import Client  # noqa: PLC0415
    from distributed.security import Security  # noqa: PLC0415

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    bindir = Path(sys.executable).parent
    info = tmp / "scheduler.json"
    logs = [open(tmp / "scheduler.log", "w"), open(tmp / "worker.log", "w")]  # noqa: SIM115
    common = ["--host", "127.0.0.1", "--no-dashboard", *(tls or [])]
    protocol = ["--protocol", "tls"] if tls else []
    listen = ["--scheduler-file", str(info)]
    security = None
    if tls:
        ca, cert, key = tls[1::2]
        security = Security(
            tls_ca_file=ca, tls_client_cert=cert, tls_client_key=key, require_encryption=True
        )
    sched = subprocess.Popen(
        [bindir / "dask", "scheduler", *common, *protocol, "--port", "0", *listen],
        env=env,
        stdout=logs[0],
        stderr=subprocess.STDOUT,
    )
    procs = [sched]
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and sched.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # waiting for another process to start (no simulated clock here)
        address = json.loads(info.read_text())["address"]
        assert address.startswith("tls://127.0.0.1:" if tls else "tcp://127.0.0.1:")
        args = [*common, "--nworkers", "1", "--nthreads", "1", "--scheduler-file", info]
        procs.append(
            subprocess.Popen(
                [bindir / "dask", "worker", *args],
                env=env,
                stdout=logs[1],
                stderr=subprocess.STDOUT,
            )
        )
        with Client(address, timeout=60, security=security) as client:
            client.wait_for_workers(1, timeout=60)
        yield address
        with Client(address, timeout=60, security=security) as client:
            client.shutdown()  # the scheduler and its workers end
        for p in reversed(procs):
            assert p.wait(timeout=60) == 0, (tmp / "worker.log").read_text()[-2000:]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        for f in logs:
            f.close()


def test_existing_scheduler_runs_the_same_tasks(archive, tmp_path, capsys):
    """validate --scheduler tls://... on a loopback cluster of `dask scheduler` + `dask
    worker` speaking TLS only (generated certificates): the files of the in-process run, live
    diagnosis included, byte for byte. The same scheduler refuses a plain-TCP client, and a
    tls:// address without the files is refused before any connection: clear one-line
    errors, nothing written."""
    paths = [str(archive / "leaky"), str(archive / "garbage.mcap")]
    ref_code, ref = run_fleet(tmp_path, "serial", paths, "--serial")
    doc = json.loads((ref / "leaky.json").read_text())
    assert any(w["diagnosis"] for w in doc["models"]["B"]["windows"])  # diagnosis in force
    tls = temporary_tls(tmp_path)
    with dask_cluster(tmp_path, tls) as address:
        code, out = run_fleet(tmp_path, "remote", paths, "--scheduler", address, *tls)
        capsys.readouterr()
        plain = address.replace("tls://", "tcp://")
        assert run_fleet(tmp_path, "plain", paths, "--scheduler", plain)[0] == cli.EXIT_ERROR
        err = capsys.readouterr().err
        assert "cannot reach the Dask scheduler" in err
        assert "drops plain connections: give its tls:// address" in err
        assert run_fleet(tmp_path, "nofiles", paths, "--scheduler", address)[0] == cli.EXIT_ERROR
        assert f"the scheduler {address} speaks TLS: give --tls-ca-file" in capsys.readouterr().err
    assert (code, files(out)) == (ref_code, files(ref))
    assert not list((tmp_path / "plain").glob("*.json"))
    assert not list((tmp_path / "nofiles").glob("*.json"))


def test_diagnose_many_recordings(archive, tmp_path, capsys):
    """diagnose DIR...: each recording's diagnosis JSON is the one it gets alone."""
    out = tmp_path / "diag"
    args = ["--model", "B", *FAST_ARGS]
    paths = [str(archive / "leaky"), str(archive / "garbage.mcap")]
    code = cli.main(["diagnose", *paths, "--out", str(out), "--serial", *args])
    assert code == fleet.EXIT_UNREADABLE
    alone_json = tmp_path / "alone.json"
    assert cli.main(["diagnose", paths[0], "--json", str(alone_json), *args]) == 0
    assert (out / "leaky.json").read_text() == alone_json.read_text()
    table = pd.read_csv(out / "summary.csv")
    assert dict(zip(table["recording"], table["status"], strict=True)) == {
        paths[0]: "complete",
        paths[1]: "unreadable",
    }


def make_bag_dir(path: Path) -> Path:
    path.mkdir(parents=True)
    (path / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    return path


def test_paths_directories_and_globs_expand_to_recordings(tmp_path):
    a = make_bag_dir(tmp_path / "2024" / "jan" / "run1")
    b = make_bag_dir(tmp_path / "2024" / "feb" / "run1")
    c = tmp_path / "2024" / "feb" / "plain.mcap"
    c.write_bytes(b"x")
    t = tmp_path / "2024" / "log.csv"
    t.write_text("t,u\n")
    note = tmp_path / "2024" / "readme.md"
    note.write_text("x")
    (tmp_path / "2024" / "empty").mkdir()
    found = fleet.expand_paths([str(tmp_path / "2024")])
    assert found.recordings == (str(c), str(b), str(a), str(t))  # a sorted walk
    assert [p for p, _ in found.skipped] == [str(note)]
    # a glob, ** at any depth; a path named twice is one recording
    got = fleet.expand_paths([str(tmp_path / "2024" / "*" / "run1"), str(a)])
    assert got.recordings == (str(b), str(a))
    assert fleet.expand_paths([str(tmp_path / "**" / "*.mcap")]).recordings == (str(c),)
    # a bag directory is one recording, not searched
    assert fleet.expand_paths([str(a)]).recordings == (str(a),)
    # the same name in two folders gets two files
    names = fleet.output_names([str(a), str(b), str(c)])
    assert len(set(names.values())) == 3
    assert names[str(a)] == "jan__run1"
    for bad in (str(tmp_path / "nope"), str(tmp_path / "*.db3"), str(tmp_path / "2024" / "empty")):
        with pytest.raises(fleet.FleetError):
            fleet.expand_paths([bad])
    # one recording named directly keeps the single command; a directory of them does not
    assert fleet.is_single([str(a)])
    assert fleet.is_single([str(tmp_path / "missing")])  # the single command's error
    assert not fleet.is_single([str(tmp_path / "2024")])
    assert not fleet.is_single([str(a), str(b)])


@dataclasses.dataclass(frozen=True)
class _Job:
    """A job of the use cases' shape that fails on the recording "b"."""

    path: str = ""

    def at(self, path: str) -> _Job:
        return _Job(path)

    def run(self) -> Outcome:
        if self.path.endswith("b"):
            raise RuntimeError("boom")
        return Outcome(ExitCode.OK, Status.COMPLETE)


def test_a_failing_task_is_one_failed_row(tmp_path):
    got = list(fleet.run_serial(_Job(), ["a", "b", "c"]))
    assert [o.status for o in got] == ["complete", "failed", "complete"]
    assert "RuntimeError: boom" in got[1].problem
    assert fleet.fleet_exit_code(got) == fleet.EXIT_UNREADABLE


def test_fleet_options_are_checked(archive, tmp_path, capsys):
    two = [str(archive / "leaky"), str(archive / "short")]
    assert cli.main(["validate", *two, *FAST_ARGS]) == cli.EXIT_ERROR
    assert "--out DIR" in capsys.readouterr().err
    code = cli.main(["validate", *two, "--json", "x.json", "--out", str(tmp_path), *FAST_ARGS])
    assert code == cli.EXIT_ERROR
    assert "--json" in capsys.readouterr().err
    code = cli.main(
        ["validate", *two, "--out", str(tmp_path), "--scheduler", "tcp://127.0.0.1:1", "--serial"]
    )
    assert code == cli.EXIT_ERROR
    assert "--scheduler" in capsys.readouterr().err
    code = cli.main(["validate", str(tmp_path / "none*"), "--out", str(tmp_path), *FAST_ARGS])
    assert code == cli.EXIT_ERROR
    assert "matches nothing" in capsys.readouterr().err
    pem = tmp_path / "ca.pem"
    pem.write_text("")
    tls = ["--tls-ca-file", str(pem), "--tls-cert", str(pem)]
    out = ["--out", str(tmp_path)]
    for scheduler, extra, why in [
        ("tcp://127.0.0.1:1", tls, "give its address as --scheduler tls://HOST:PORT"),
        ("tls://127.0.0.1:1", tls[:2], "TLS needs --tls-ca-file CA"),
        ("tls://127.0.0.1:1", [*tls, "--tls-key", str(pem) + "x"], "ca.pemx: no such file"),
    ]:
        code = cli.main(["validate", *two, *out, "--scheduler", scheduler, *extra])
        assert code == cli.EXIT_ERROR
        assert why in capsys.readouterr().err


def test_an_unreachable_scheduler_is_a_clear_error(archive, tmp_path, capsys):
    import dask  # noqa: PLC0415

    with socket.socket() as s:  # a loopback port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        code = cli.main(
            [
                "validate",
                str(archive / "leaky"),
                "--out",
                str(tmp_path),
                "--scheduler",
                f"tcp://127.0.0.1:{port}",
                *FAST_ARGS,
            ]
        )
    assert code == cli.EXIT_ERROR
    assert "cannot reach the Dask scheduler" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.json"))


def test_the_fleet_figure_plots_what_the_alarm_uses(tmp_path) -> None:
    """Windows raised by the operating point (a leak: β small, β_op large) sit above 1."""
    from twotank_validation.usecases import ReadSettings, ValidateJob  # noqa: PLC0415

    # the leak after the operating point is commissioned (about 4 periods in)
    leaky = fast_scenario("leak", periods=10, faults=("leak=0.04@900",))
    write_scenario_bag(leaky, tmp_path / "leaky", progress=False)
    read = ReadSettings(ts_s=0.8, period_samples=256)
    job = ValidateJob(str(tmp_path / "leaky"), read, ("B",), diagnosis=False)
    outcome = fleet.RecordingOutcome.of(job.recording, job.run())
    windows = outcome.timeline["models"]["B"]["windows"]
    raised = [w for w in windows if w["alarm"] == "ERROR" and w["raised_by"] == "operating point"]
    assert raised, "the leak should raise the alarm through the operating point"
    assert all(w["beta"] < 1.0 for w in raised)  # the dynamic β alone is below the limit
    fig = fleet.fleet_figure([outcome], ["B"])
    ax = fig.axes[0]
    (bars,) = [c for c in ax.collections if c.get_gid() == "beta_total"]
    judged = [w for w in windows if w["beta"] is not None]
    plotted = dict(zip([w["end"] for w in judged], bars.get_array(), strict=True))
    for w in raised:  # the reference: sqrt(β² + β_op²), computed here from the parts
        total = (w["beta"] ** 2 + w["beta_op"] ** 2) ** 0.5
        assert plotted[w["end"]] == pytest.approx(total, rel=1e-9)
        assert plotted[w["end"]] > 1.0
    assert "(s)" in ax.get_xlabel()
    assert ax.get_ylabel()
    assert "β_total" in fig.axes[-1].get_ylabel()  # the colour bar: the quantity and its unit
    assert "dimensionless" in fig.axes[-1].get_ylabel()
