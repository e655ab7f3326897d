"""Closed-loop rig: `ros2 launch twotank_validation twotank_closed_loop.launch.py`.

The simulated plant, the PI controller (which adds the excitation to its output or its
setpoints), the validator, fed the controller's `flow_cmd` and the measurements, and the
supervisor, which watches `supervisor_models` (default B) and switches the controller to
its safe mode on their alarm or silence (`control/mode`).
Arguments: `models` (comma-separated, default A,B), `faults` (comma-separated fault specs,
e.g. `leak=0.06@1000`), `real_time_factor` (default 1; > 1 runs the plant's /clock faster),
`excitation_entry` (`output` or `setpoint`, default output). The plant owns the simulated
clock (/clock); every node uses it. The validator's input periodicity gate is opened
(`input_periodic_rtol` 0.25): closed-loop commands are not periodic. `control/mode`
(std_msgs/String "normal"/"safe", transient-local) switches the controller's safe mode. Not
exercised by the test suite (no launch wheels on PyPI); `twotank-validation live
--closed-loop` composes the same nodes in-process.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

CLOSED_LOOP_INPUT_PERIODIC_RTOL = 0.25  # twotank_validation.sim.control's value


def _nodes(context, *args, **kwargs):
    models = [m for m in LaunchConfiguration("models").perform(context).split(",") if m]
    faults = [f for f in LaunchConfiguration("faults").perform(context).split(",") if f] or [""]
    rtf = float(LaunchConfiguration("real_time_factor").perform(context))
    entry = LaunchConfiguration("excitation_entry").perform(context)
    supervised = [
        m for m in LaunchConfiguration("supervisor_models").perform(context).split(",") if m
    ]
    sim = {"use_sim_time": True}
    return [
        Node(
            package="twotank_validation",
            executable="twotank_plant",
            parameters=[{**sim, "publish_clock": True, "real_time_factor": rtf, "faults": faults}],
        ),
        Node(
            package="twotank_validation",
            executable="twotank_controller",
            parameters=[{**sim, "excitation_entry": entry}],
        ),
        Node(
            package="twotank_validation",
            executable="twotank_validator",
            parameters=[
                {
                    **sim,
                    "models": models,
                    "input_periodic_rtol": CLOSED_LOOP_INPUT_PERIODIC_RTOL,
                }
            ],
        ),
        Node(
            package="twotank_validation",
            executable="twotank_supervisor",
            parameters=[{**sim, "models": supervised}],
        ),
    ]


def generate_launch_description():
    """Launch description (ROS 2 launch entry point)."""
    return LaunchDescription(
        [
            DeclareLaunchArgument("models", default_value="A,B"),
            DeclareLaunchArgument("supervisor_models", default_value="B"),
            DeclareLaunchArgument("faults", default_value=""),
            DeclareLaunchArgument("real_time_factor", default_value="1.0"),
            DeclareLaunchArgument("excitation_entry", default_value="output"),
            OpaqueFunction(function=_nodes),
        ]
    )
