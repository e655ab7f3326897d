"""Validator alone, on a real rig: `ros2 launch twotank_validation twotank_validator.launch.py`.

Remap `flow_cmd`, `height` and `temperature` to the rig's topics and set the unit
conversions (`pascal_per_unit`, `temperature_offset_c`, `temperature_span_c`) if they differ,
e.g. in a `params_file`. Arguments: `params_file`, `namespace`, `use_sim_time` (default
false), `log_level` (default info), `autostart` (default true: launch configures and
activates the validator; false: it waits unconfigured), `models` (comma-separated) and
`latch_alarm`; an argument
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
from twotank_validation.ros.validator_node import VALIDATOR_PARAMS

VALIDATOR_ARGS = {"models": "models", "latch_alarm": "latch_alarm"}
ARGUMENTS = (
    *common_arguments(use_sim_time=False),
    *parameter_arguments(VALIDATOR_PARAMS, VALIDATOR_ARGS),
)


def _nodes(context, *args, **kwargs):
    values = {a.name: LaunchConfiguration(a.name).perform(context) for a in ARGUMENTS}
    return [
        LifecycleNode(
            package="twotank_validation",
            executable="twotank_validator",
            remappings=[
                ("flow_cmd", "flow_cmd"),
                ("height", "height"),
                ("temperature", "temperature"),
            ],
            **lifecycle_options(values, "twotank_validator", VALIDATOR_PARAMS, VALIDATOR_ARGS),
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
