"""The package's ROS 2 messages: build, CDR round trips with rclpy, decoding with rosbags.

The messages are the top-level ``msg/*.msg`` files, generated as the ROS package
``twotank_validation_msgs`` (CMake project in the folder ``twotank_validation_msgs/``) by
``scripts/build_msgs.sh``, which ``scripts/run`` calls. No node or DDS participant is started
here: serialisation needs no ``rclpy.init()``. The slow test builds both ROS packages of the
repository with colcon in a temporary workspace (``twotank_validation``: ament_python from
``setup.py``, the same entry points and data files as the pip install).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import math
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path
from typing import Any

import numpy as np
import pytest

try:
    from twotank_validation_msgs.msg import FlowCommand, ValidationReport
except ImportError as err:  # pragma: no cover - depends on the install
    raise ImportError(
        "twotank_validation_msgs is not built into this Python environment: run "
        "`bash scripts/run test` (its bootstrap runs scripts/build_msgs.sh)"
    ) from err
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from std_msgs.msg import Header

import twotank_validation

ROOT = Path(__file__).resolve().parents[2]
MSG_DIR = ROOT / "msg"
PKG = "twotank_validation_msgs"

# colcon for the workspace test, installed into a throwaway venv (colcon-core pulls pytest
# plugins and setuptools<80, which must not enter the project venv).
COLCON_REQUIREMENTS = tuple(
    ln.strip()
    for ln in (ROOT / "requirements-colcon.txt").read_text().splitlines()
    if ln.strip() and not ln.startswith("#")
)


def make_flow_command() -> Any:
    return FlowCommand(
        header=Header(stamp=Time(sec=1_700_000_000, nanosec=123_456_789), frame_id="rig"),
        hot=0.25,
        cold=0.75,
    )


def make_report() -> Any:
    return ValidationReport(
        header=Header(stamp=Time(sec=1_700_000_409, nanosec=500_000_000), frame_id="rig"),
        model="A",
        window_start=Time(sec=1_700_000_000, nanosec=100_000_000),
        window_end=Time(sec=1_700_000_409, nanosec=500_000_000),
        n_periods=2,
        n_samples=4096,
        judged=True,
        data_quality="ok",
        beta=1.292,
        beta_lower=1.291,
        beta_upper=1.293,
        margin=-0.292,
        invalidated=True,
        alarm_level=ValidationReport.ERROR,
        norm_convention="power",
        solver="closed_form",
        frequencies_hz=[0.0, 0.0048828125, 0.009765625],
        w_min=[0.01, 0.5, 1.292],
        compute_time_s=0.0019,
        excited_bins=[1, 2],
        noise_floor=[0.0, 0.05, 0.07],
        noise_beta=0.12,
    )


REPORT_SCALARS = {
    "model": "A",
    "n_periods": 2,
    "n_samples": 4096,
    "judged": True,
    "data_quality": "ok",
    "beta": 1.292,
    "beta_lower": 1.291,
    "beta_upper": 1.293,
    "margin": -0.292,
    "invalidated": True,
    "alarm_level": 2,
    "norm_convention": "power",
    "solver": "closed_form",
    "compute_time_s": 0.0019,
    "noise_beta": 0.12,
}
REPORT_ARRAYS = {
    "frequencies_hz": [0.0, 0.0048828125, 0.009765625],
    "w_min": [0.01, 0.5, 1.292],
    "excited_bins": [1, 2],
    "noise_floor": [0.0, 0.05, 0.07],
}


def stamp_of(time: Any) -> tuple[int, int]:
    return (time.sec, time.nanosec)


def check_report(msg: Any) -> None:
    """Every field of make_report(); works for rclpy and rosbags messages alike."""
    for name, value in REPORT_SCALARS.items():
        assert getattr(msg, name) == value, name
    for name, values in REPORT_ARRAYS.items():
        np.testing.assert_array_equal(np.asarray(getattr(msg, name)), values, err_msg=name)
    assert stamp_of(msg.header.stamp) == (1_700_000_409, 500_000_000)
    assert msg.header.frame_id == "rig"
    assert stamp_of(msg.window_start) == (1_700_000_000, 100_000_000)
    assert stamp_of(msg.window_end) == (1_700_000_409, 500_000_000)


def msg_fields(path: Path) -> list[str]:
    """Field names of a .msg file, in order (constants and comments left out)."""
    names = []
    for line in path.read_text().splitlines():
        body = line.split("#", 1)[0].strip()
        if body and "=" not in body:
            names.append(body.split()[1])
    return names


def test_messages_come_from_their_own_package_not_the_core() -> None:
    """The generated module must not shadow or collide with the Python package."""
    import twotank_validation_msgs  # noqa: PLC0415

    assert Path(twotank_validation.__file__).resolve().parent == ROOT / "twotank_validation"
    assert Path(twotank_validation_msgs.__file__).resolve().parent.parent != ROOT
    assert importlib.util.find_spec("twotank_validation.msg") is None
    assert FlowCommand.__module__ == f"{PKG}.msg._flow_command"
    assert ValidationReport.__module__ == f"{PKG}.msg._validation_report"


@pytest.mark.parametrize("msg_class", [FlowCommand, ValidationReport])
def test_built_fields_match_the_msg_files(msg_class: Any) -> None:
    """msg/*.msg is the single source of truth and the installed build is up to date."""
    built = list(msg_class.get_fields_and_field_types())
    assert built == msg_fields(MSG_DIR / f"{msg_class.__name__}.msg")


def test_alarm_levels_are_the_diagnostic_status_levels() -> None:
    assert (
        ValidationReport.OK,
        ValidationReport.WARN,
        ValidationReport.ERROR,
        ValidationReport.STALE,
    ) == (0, 1, 2, 3)
    for name in ("OK", "WARN", "ERROR", "STALE"):
        assert getattr(ValidationReport, name) == int.from_bytes(getattr(DiagnosticStatus, name))


def test_flow_command_round_trip() -> None:
    back = deserialize_message(serialize_message(make_flow_command()), FlowCommand)
    assert stamp_of(back.header.stamp) == (1_700_000_000, 123_456_789)
    assert back.header.frame_id == "rig"
    assert (back.hot, back.cold) == (0.25, 0.75)
    assert back == make_flow_command()


def test_validation_report_round_trip() -> None:
    back = deserialize_message(serialize_message(make_report()), ValidationReport)
    check_report(back)
    assert back == make_report()
    assert back.STALE == 3


def test_validation_report_not_judged_keeps_nan() -> None:
    report = ValidationReport(judged=False, data_quality="too short", beta=math.nan)
    back = deserialize_message(serialize_message(report), ValidationReport)
    assert math.isnan(back.beta)
    assert (back.judged, back.data_quality) == (False, "too short")


def kilted_store_with(name: str) -> Any:
    """ROS2_KILTED type store plus twotank_validation_msgs/msg/<name> read from msg/."""
    store = get_typestore(Stores.ROS2_KILTED)
    text = (MSG_DIR / f"{name}.msg").read_text()
    store.register(get_types_from_msg(text, f"{PKG}/msg/{name}"))
    return store


def test_rosbags_decodes_validation_report_serialised_by_rclpy() -> None:
    store = kilted_store_with("ValidationReport")
    raw = bytes(serialize_message(make_report()))
    msg = store.deserialize_cdr(raw, f"{PKG}/msg/ValidationReport")
    check_report(msg)
    assert (msg.OK, msg.WARN, msg.ERROR, msg.STALE) == (0, 1, 2, 3)
    # And back (not byte for byte: rclpy leaves alignment padding uninitialised).
    again = bytes(store.serialize_cdr(msg, f"{PKG}/msg/ValidationReport"))
    assert deserialize_message(again, ValidationReport) == make_report()


def test_rosbags_decodes_a_report_whose_sequences_are_all_empty() -> None:
    """A window not judged: every sequence empty, each read where rclpy wrote it.

    rclpy and rosbags pad an empty float64 sequence differently when a 4-byte-aligned field
    follows it; every float64 sequence of the message is followed by a float64.
    """
    store = kilted_store_with("ValidationReport")
    empty = ValidationReport(
        model="B", judged=False, data_quality="settling", beta=math.nan, beta_outside=math.nan,
        input_noise=0.25, input_noise_effect=0.5, noise_beta=math.nan, compute_time_s=0.125,
    )  # fmt: skip
    msg = store.deserialize_cdr(bytes(serialize_message(empty)), f"{PKG}/msg/ValidationReport")
    for name in ("frequencies_hz", "w_min", "lines_outside", "excited_bins", "noise_floor"):
        assert len(getattr(msg, name)) == 0, name
    assert (msg.model, msg.data_quality, msg.compute_time_s) == ("B", "settling", 0.125)
    assert (msg.input_noise, msg.input_noise_effect) == (0.25, 0.5)
    assert math.isnan(msg.noise_beta)
    again = bytes(store.serialize_cdr(msg, f"{PKG}/msg/ValidationReport"))
    assert deserialize_message(again, ValidationReport).input_noise_effect == 0.5


def test_rosbags_decodes_flow_command_serialised_by_rclpy() -> None:
    store = kilted_store_with("FlowCommand")
    raw = bytes(serialize_message(make_flow_command()))
    msg = store.deserialize_cdr(raw, f"{PKG}/msg/FlowCommand")
    assert (msg.hot, msg.cold) == (0.25, 0.75)
    assert stamp_of(msg.header.stamp) == (1_700_000_000, 123_456_789)
    again = bytes(store.serialize_cdr(msg, f"{PKG}/msg/FlowCommand"))
    assert deserialize_message(again, FlowCommand) == make_flow_command()


def run_logged(cmd: list[str], log: Path, **kwargs: Any) -> subprocess.CompletedProcess[str]:
    """Run cmd with output to log; bounded so that a hung build cannot stall the suite."""
    with log.open("a") as out:
        out.write(f"$ {' '.join(cmd)}\n")
        out.flush()
        return subprocess.run(
            cmd, stdout=out, stderr=subprocess.STDOUT, text=True, timeout=600, check=False, **kwargs
        )


def console_scripts(dist: importlib.metadata.Distribution) -> dict[str, str]:
    return {ep.name: ep.value for ep in dist.entry_points if ep.group == "console_scripts"}


def names(folder: Path, pattern: str) -> list[str]:
    return sorted(p.name for p in folder.glob(pattern))


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("cmake") is None, reason="cmake is not installed")
def test_colcon_builds_both_packages(tmp_path: Path) -> None:
    """colcon (from PyPI) builds twotank_validation_msgs and twotank_validation.

    The ROS 2 underlay is this venv (its PyPI wheels). The folder twotank_validation_msgs/ is
    named as a base path of its own because colcon does not descend into a package folder
    (the repository root is the ament_python package twotank_validation). The install layout
    is ament_python's: console scripts in lib/twotank_validation, launch files, models and
    scenarios in share/twotank_validation, the Python package with its package data in
    site-packages; the console scripts are the ones the pip install of setup.py has.
    """
    log = tmp_path / "colcon-test.log"
    venv_python = Path(sys.executable)
    prefix = Path(sys.prefix)
    # scripts/run installs colcon into a venv of its own before the (offline) test run
    tools = Path(os.environ.get("TWOTANK_COLCON_VENV", prefix / "colcon-venv"))
    if not (tools / "bin/colcon").exists():
        if run_logged([sys.executable, "-m", "venv", str(tools)], log).returncode != 0:
            pytest.fail(f"could not create a venv for colcon:\n{log.read_text()[-3000:]}")
        pip = run_logged(
            [str(tools / "bin/python"), "-m", "pip", "install", "-q", *COLCON_REQUIREMENTS], log
        )
        assert pip.returncode == 0, (
            "colcon is not installed and could not be installed (run the tests through "
            f"`bash scripts/run test`, which installs it):\n{log.read_text()[-2000:]}"
        )
    # colcon builds an ament_python package with the interpreter colcon runs on (`setup.py
    # install`), and that interpreter goes into the #! line of the console scripts. A ROS
    # install has one Python for both; here colcon sits in a venv of its own, so its code runs
    # on this venv's interpreter (as `python -m colcon` would), with the colcon venv's
    # site-packages on the path of the colcon process only: setup.py runs with this venv's
    # setuptools, the launchers start this venv's Python. setup.py needs colcon_core alone
    # (colcon adds its distutils command symlink_data), from a folder on PYTHONPATH.
    colcon_site = sysconfig.get_path("purelib", vars={"base": str(tools), "platbase": str(tools)})
    colcon = [
        str(venv_python),
        "-c",
        f"import sys; sys.path.insert(0, {colcon_site!r}); "
        "from colcon_core.command import main; sys.exit(main())",
    ]
    colcon_core_only = tmp_path / "colcon_core_only"
    colcon_core_only.mkdir()
    (colcon_core_only / "colcon_core").symlink_to(Path(colcon_site, "colcon_core"))

    src = tmp_path / "ws/src/twotank_validation"
    ignore = shutil.ignore_patterns(
        ".git", ".venv", "__pycache__", ".*_cache", ".hypothesis", "build", "install", "log"
    )
    shutil.copytree(ROOT, src, ignore=ignore)
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in {"PYTHONPATH", "LD_LIBRARY_PATH", "COLCON_PREFIX_PATH"}
    }
    env |= {"AMENT_PREFIX_PATH": str(prefix), "CMAKE_PREFIX_PATH": str(prefix)}
    build = run_logged(
        [
            *colcon,
            "build",
            "--base-paths",
            "src",
            f"src/twotank_validation/{PKG}",
            "--cmake-args",
            f"-DPython3_EXECUTABLE={venv_python}",
            "-DBUILD_TESTING=OFF",
        ],
        log,
        cwd=tmp_path / "ws",
        env=env | {"PYTHONPATH": str(colcon_core_only)},
    )
    assert build.returncode == 0, f"colcon build failed:\n{log.read_text()[-6000:]}"

    install = tmp_path / "ws/install"
    site = sysconfig.get_path("purelib", vars={"base": "", "platbase": ""}).lstrip("/")
    own = install / "twotank_validation"
    share = own / "share/twotank_validation"
    (built,) = (
        d
        for d in importlib.metadata.distributions(path=[str(own / site)])
        if d.metadata["Name"] == "twotank_validation"
    )
    scripts = console_scripts(built)
    assert set(scripts) == {
        "twotank_validator",
        "twotank_plant",
        "twotank_model_plant",
        "twotank_excitation",
        "twotank_controller",
        "twotank_supervisor",
        "twotank-validation",
    }
    assert scripts == console_scripts(importlib.metadata.distribution("twotank_validation"))
    assert scripts["twotank_validator"] == "twotank_validation.ros.validator_node:main"
    launchers = own / "lib/twotank_validation"
    for name in scripts:
        assert os.access(launchers / name, os.X_OK), name
        assert (launchers / name).read_text().startswith(f"#!{venv_python}\n"), name
    assert (own / "share/ament_index/resource_index/packages/twotank_validation").is_file()
    assert (share / "package.xml").read_text() == (ROOT / "package.xml").read_text()
    assert names(share / "launch", "*") == names(ROOT / "launch", "*.launch.py")
    assert len(names(share / "launch", "*")) == 4
    assert names(share / "models", "*") == ["model_a.yaml", "model_b.yaml"]
    package = ROOT / "twotank_validation"
    assert names(share / "scenarios", "*") == names(package / "sim/scenarios", "*.yaml")
    assert names(share / "layouts", "*") == ["twotank_foxglove.json", "twotank_plotjuggler.xml"]
    assert names(share / "security", "*") == ["twotank_policy.xml"]
    assert names(share / "config", "*") == ["twotank_analyzers.yaml"]
    # package data (importlib.resources), next to the modules
    installed = own / site / "twotank_validation"
    assert names(installed / "models", "*.yaml") == ["model_a.yaml", "model_b.yaml"]
    assert names(installed / "sim/scenarios", "*") == names(package / "sim/scenarios", "*.yaml")
    assert (install / PKG / "share" / PKG / "msg/ValidationReport.msg").read_text() == (
        MSG_DIR / "ValidationReport.msg"
    ).read_text()

    # In the workspace's environment (colcon's setup.sh), both come from install/.
    probe = (
        "import twotank_validation, twotank_validation_msgs.msg as m; "
        "from importlib.resources import files; "
        "print(twotank_validation.__file__); print(m.__file__); "
        "print(m.ValidationReport.STALE, m.FlowCommand(hot=0.5).hot); "
        "print(files(twotank_validation).joinpath('models', 'model_a.yaml').is_file())"
    )
    shell = subprocess.run(
        ["sh", "-c", f'. ./setup.sh && exec "{venv_python}" -c "{probe}"'],
        cwd=install,
        env={k: v for k, v in env.items() if k not in {"AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH"}},
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert shell.returncode == 0, shell.stderr
    core_file, msgs_file, values, model_found = shell.stdout.split("\n")[:4]
    assert core_file.startswith(str(own / site))
    assert msgs_file.startswith(str(install / PKG / site))
    assert values == "3 0.5"
    assert model_found == "True"
    cli = subprocess.run(
        ["sh", "-c", f'. ./setup.sh && exec "{launchers / "twotank-validation"}" --help'],
        cwd=install,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert cli.returncode == 0, cli.stderr
    assert "demo" in cli.stdout
