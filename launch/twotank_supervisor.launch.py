"""Supervisor: `ros2 launch twotank_validation twotank_supervisor.launch.py`.

Starts the supervisor beside a running validator (e.g. `twotank_sim.launch.py`, or the
validator on a rig): it watches `validation/M/invalidated` and `validation/M/report` of the
given models and publishes `control/mode` for the controller. Arguments: `models`
(comma-separated, default B), `latch` (default false), `clear_after_s` (default 204.8),
`clear_reports` (default 2), `stale_after_s` (default 180), `startup_grace_s` (default 900),
`use_sim_time` (default false; true beside the simulated rig, whose plant owns /clock).
Not exercised by the test suite (no launch wheels on PyPI); test/online/test_supervisor.py runs the
node in-process.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def _nodes(context, *args, **kwargs):
    def arg(name):
        return LaunchConfiguration(name).perform(context)

    models = [m for m in arg("models").split(",") if m]
    params = {
        "models": models,
        "latch": arg("latch").lower() == "true",
        "clear_after_s": float(arg("clear_after_s")),
        "clear_reports": int(arg("clear_reports")),
        "stale_after_s": float(arg("stale_after_s")),
        "startup_grace_s": float(arg("startup_grace_s")),
        "use_sim_time": arg("use_sim_time").lower() == "true",
    }
    return [
        Node(package="twotank_validation", executable="twotank_supervisor", parameters=[params])
    ]


def generate_launch_description():
    """Launch description (ROS 2 launch entry point)."""
    return LaunchDescription(
        [
            DeclareLaunchArgument("models", default_value="B"),
            DeclareLaunchArgument("latch", default_value="false"),
            DeclareLaunchArgument("clear_after_s", default_value="204.8"),
            DeclareLaunchArgument("clear_reports", default_value="2"),
            DeclareLaunchArgument("stale_after_s", default_value="180.0"),
            DeclareLaunchArgument("startup_grace_s", default_value="900.0"),
            DeclareLaunchArgument("use_sim_time", default_value="false"),
            OpaqueFunction(function=_nodes),
        ]
    )
