"""Simulated rig, excitation and validator: `ros2 launch twotank_validation twotank_sim.launch.py`.

Arguments: `models` (comma-separated, default A,B), `faults` (comma-separated fault specs,
e.g. `leak=0.02@1000`), `real_time_factor` (default 1; > 1 runs the plant's /clock faster).
The plant owns the simulated clock (/clock); every node uses it. Not exercised by the test
suite (no launch wheels on PyPI); `twotank-validation live` composes the same nodes in-process.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def _nodes(context, *args, **kwargs):
    models = [m for m in LaunchConfiguration("models").perform(context).split(",") if m]
    faults = [f for f in LaunchConfiguration("faults").perform(context).split(",") if f] or [""]
    rtf = float(LaunchConfiguration("real_time_factor").perform(context))
    sim = {"use_sim_time": True}
    return [
        Node(
            package="twotank_validation",
            executable="twotank_plant",
            parameters=[{**sim, "publish_clock": True, "real_time_factor": rtf, "faults": faults}],
        ),
        Node(package="twotank_validation", executable="twotank_excitation", parameters=[sim]),
        Node(
            package="twotank_validation",
            executable="twotank_validator",
            parameters=[{**sim, "models": models}],
        ),
    ]


def generate_launch_description():
    """Launch description (ROS 2 launch entry point)."""
    return LaunchDescription(
        [
            DeclareLaunchArgument("models", default_value="A,B"),
            DeclareLaunchArgument("faults", default_value=""),
            DeclareLaunchArgument("real_time_factor", default_value="1.0"),
            OpaqueFunction(function=_nodes),
        ]
    )
