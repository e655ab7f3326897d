"""Supervisor: `ros2 launch twotank_validation twotank_supervisor.launch.py`.

Starts the supervisor beside a running validator (e.g. `twotank_sim.launch.py`, or the
validator on a rig): it watches `validation/M/invalidated` and `validation/M/report` of the
given models and publishes `control/mode` for the controller. Arguments: `params_file`,
`namespace` (the validator's), `use_sim_time` (default false; true beside the simulated rig,
whose plant owns /clock), `log_level`, `autostart` (default true), and the supervisor's `models`
(comma-separated),
`latch`, `clear_after_s`, `clear_reports`, `stale_after_s`, `startup_grace_s`; an argument
left empty leaves the parameter to the params file or the node's default.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode

from launch import LaunchDescription
from twotank_validation.ros.launching import (
    common_arguments,
    lifecycle_options,
    parameter_arguments,
)
from twotank_validation.ros.supervisor_node import SUPERVISOR_PARAMS

SUPERVISOR_ARGS = {
    name: name
    for name in (
        "models",
        "latch",
        "clear_after_s",
        "clear_reports",
        "stale_after_s",
        "startup_grace_s",
        # the ros2_control switch (docs/ros.md, ros2_control)
        "controller_manager",
        "normal_controllers",
        "fallback_controllers",
        "switch_strictness",
        "switch_timeout_s",
    )
}
ARGUMENTS = (
    *common_arguments(use_sim_time=False),
    *parameter_arguments(SUPERVISOR_PARAMS, SUPERVISOR_ARGS),
)


def _nodes(context, *args, **kwargs):
    values = {a.name: LaunchConfiguration(a.name).perform(context) for a in ARGUMENTS}
    return [
        LifecycleNode(
            package="twotank_validation",
            executable="twotank_supervisor",
            **lifecycle_options(values, "twotank_supervisor", SUPERVISOR_PARAMS, SUPERVISOR_ARGS),
        )
    ]


def generate_launch_description():
    """Launch description (ROS 2 launch entry point)."""
    return LaunchDescription(
        [
            *(
                DeclareLaunchArgument(
                    a.name,
                    default_value=a.default,
                    description=a.description,
                    choices=list(a.choices) or None,
                )
                for a in ARGUMENTS
            ),
            OpaqueFunction(function=_nodes),
        ]
    )
