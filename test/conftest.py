"""Shared test configuration: a deterministic hypothesis profile."""

import os

from hypothesis import HealthCheck, settings

# DDS discovery stays on loopback, in a domain of the project's own (also set by scripts/run).
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "77")
# Under pytest-xdist (scripts/run test runs one worker per core) each worker process gets a
# domain of its own, so that two workers' node tests never see each other's participants.
_worker = os.environ.get("PYTEST_XDIST_WORKER", "")  # "gw0", "gw1", ... or unset
if _worker.startswith("gw"):
    os.environ["ROS_DOMAIN_ID"] = str(int(os.environ["ROS_DOMAIN_ID"]) + 1 + int(_worker[2:]))

settings.register_profile(
    "ci",
    derandomize=True,
    deadline=None,
    max_examples=25,
    suppress_health_check=[HealthCheck.too_slow],
    print_blob=True,
)
settings.register_profile("dev", deadline=None, max_examples=100)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
