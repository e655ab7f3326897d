"""Build description of twotank_validation, the one list for colcon and pip alike.

colcon builds this folder as the ROS 2 package twotank_validation (package.xml, build type
ament_python: `setup.py install`, console scripts into lib/twotank_validation as setup.cfg
says, so that `ros2 run twotank_validation <name>` finds them); pip installs it as a plain
Python distribution (`pip install -e .` in scripts/run, or `pip install .`: console scripts
into the environment's bin/). Both take the entry points, package data and data files below.

The ROS interfaces are the separate package twotank_validation_msgs (folder
twotank_validation_msgs/, a CMake project generating the top-level msg/*.msg): colcon builds it
as a package of its own, scripts/build_msgs.sh builds it into the venv on the pip path. colcon
does not look for packages inside a package folder, so a workspace names that folder too, e.g.
with this repository at src/twotank_validation:

    colcon build --base-paths src src/twotank_validation/twotank_validation_msgs

(or --paths src/twotank_validation src/twotank_validation/twotank_validation_msgs).

Data files are globbed, relative to this file: a folder that does not exist (yet) installs
nothing, and a new launch file, model or scenario needs no edit here.
"""

from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "twotank_validation"
HERE = Path(__file__).resolve().parent
SHARE = f"share/{PACKAGE}"

# Package data (inside the Python package, found with importlib.resources), relative to
# twotank_validation/; the YAML files are also installed under share/ below.
MODELS = "models/*.yaml"
SCENARIOS = "sim/scenarios/*.yaml"
# the live diagnosis's answer probabilities (fitted by bench/bench_isolation.py --calibrate)
ANSWER_PROBABILITY = "diagnose/answer_probability.json"
VIEW_PAGE = "view/static/*"


def _files(pattern: str) -> list[str]:
    """Files matching pattern, relative to this directory (sorted; [] if there are none)."""
    return sorted(p.relative_to(HERE).as_posix() for p in HERE.glob(pattern) if p.is_file())


def _data_files() -> list[tuple[str, list[str]]]:
    """(destination, files) pairs under the install prefix; empty groups are left out."""
    groups = [
        # ament index marker and manifest: `ros2 pkg`, `ros2 run` and `ros2 launch` find the
        # package through them
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (SHARE, ["package.xml"]),
        (f"{SHARE}/launch", _files("launch/*.launch.py")),
        (f"{SHARE}/models", _files(f"{PACKAGE}/{MODELS}")),
        (f"{SHARE}/scenarios", _files(f"{PACKAGE}/{SCENARIOS}")),
        # Foxglove/Lichtblick and PlotJuggler layouts of the reports (docs/view.md)
        (f"{SHARE}/layouts", _files("layouts/*")),
        # the SROS2 access-control policy of the nodes (docs/ros.md, "Security")
        (f"{SHARE}/security", _files("security/*.xml")),
        # diagnostic_aggregator analyzers of the nodes' /diagnostics statuses (docs/ros.md)
        (f"{SHARE}/config", _files("config/*.yaml")),
    ]
    return [(dest, files) for dest, files in groups if files]


def _requirements() -> list[str]:
    lines = (HERE / "requirements.txt").read_text().splitlines()
    return [ln.strip() for ln in lines if ln.strip() and not ln.startswith("#")]


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench", "tools", "tools.*"]),
    package_data={PACKAGE: [MODELS, SCENARIOS, ANSWER_PROBABILITY, VIEW_PAGE, "py.typed"]},
    data_files=_data_files(),
    install_requires=_requirements(),
    zip_safe=True,
    maintainer="twotank_validation developers",
    maintainer_email="twotank-validation@users.noreply.github.com",
    description="Frequency-domain model validation of LFT robust-control models (Smith 1995).",
    license="BSD-3-Clause",
    python_requires=">=3.11",
    entry_points={
        "console_scripts": [
            "twotank-validation = twotank_validation.cli:main",
            "twotank_validator = twotank_validation.ros.validator_node:main",
            "twotank_plant = twotank_validation.ros.plant_node:main",
            "twotank_model_plant = twotank_validation.ros.model_plant_node:main",
            "twotank_excitation = twotank_validation.ros.excitation_node:main",
            "twotank_controller = twotank_validation.ros.controller_node:main",
            "twotank_supervisor = twotank_validation.ros.supervisor_node:main",
        ],
    },
)
