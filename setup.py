"""Install twotank_validation (ament_python layout; also a plain pip package)."""

from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "twotank_validation"
HERE = Path(__file__).parent


def _requirements() -> list[str]:
    lines = (HERE / "requirements.txt").read_text().splitlines()
    return [ln.strip() for ln in lines if ln.strip() and not ln.startswith("#")]


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench", "tools", "tools.*"]),
    package_data={PACKAGE: ["models/*.yaml", "scenarios/*.yaml", "py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/msg", [str(p) for p in sorted(Path("msg").glob("*.msg"))]),
        (
            f"share/{PACKAGE}/models",
            [str(p) for p in sorted(Path(PACKAGE, "models").glob("*.yaml"))],
        ),
    ],
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
            "twotank_excitation = twotank_validation.ros.excitation_node:main",
        ],
    },
)
