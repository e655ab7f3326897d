"""Validator alone, on a real rig: `ros2 launch twotank_validation twotank_validator.launch.py`.

Remap `flow_cmd`, `height` and `temperature` to the rig's topics and set the unit
conversions (`pascal_per_unit`, `temperature_offset_c`, `temperature_span_c`) if they differ,
e.g. in a `params_file`. Arguments: `params_file`, `namespace`, `use_sim_time` (default
false), `log_level` (default info), `models` (comma-separated) and `latch_alarm`; an argument
left empty leaves the parameter to the params file or the node's default.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription
from twotank_validation.ros.launching import common_arguments, node_options, parameter_arguments
from twotank_validation.ros.validator_node import VALIDATOR_PARAMS

VALIDATOR_ARGS = {"models": "models", "latch_alarm": "latch_alarm"}
ARGUMENTS = (
    *common_arguments(use_sim_time=False),
    *parameter_arguments(VALIDATOR_PARAMS, VALIDATOR_ARGS),
)


def _nodes(context, *args, **kwargs):
    values = {a.name: LaunchConfiguration(a.name).perform(context) for a in ARGUMENTS}
    return [
        Node(
            package="twotank_validation",
            executable="twotank_validator",
            remappings=[
                ("flow_cmd", "flow_cmd"),
                ("height", "height"),
                ("temperature", "temperature"),
            ],
            **node_options(values, VALIDATOR_PARAMS, VALIDATOR_ARGS),
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
