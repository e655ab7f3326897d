"""Simulated rig, excitation and validator: `ros2 launch twotank_validation twotank_sim.launch.py`.

Arguments: `params_file`, `namespace`, `use_sim_time` (default true: the plant owns /clock
and every node uses it), `log_level`, `autostart` (default true), `models` (the validator's,
comma-separated), `faults`
(comma-separated fault specs, e.g. `leak=0.02@1000`), `real_time_factor` (> 1 runs the plant's
/clock faster); an argument left empty leaves the parameter to the params file or the node's
default. Not run by the test suite (no launch wheels on PyPI; test/test_launch_files.py runs
its logic with stand-ins); `twotank-validation live` composes the same nodes in-process.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node

from launch import LaunchDescription
from twotank_validation.ros.excitation_node import EXCITATION_PARAMS
from twotank_validation.ros.launching import (
    common_arguments,
    lifecycle_options,
    node_options,
    parameter_arguments,
)
from twotank_validation.ros.plant_node import PLANT_PARAMS
from twotank_validation.ros.validator_node import VALIDATOR_PARAMS

PLANT_ARGS = {"faults": "faults", "real_time_factor": "real_time_factor"}
VALIDATOR_ARGS = {"models": "models"}
ARGUMENTS = (
    *common_arguments(use_sim_time=True),
    *parameter_arguments(PLANT_PARAMS, PLANT_ARGS),
    *parameter_arguments(VALIDATOR_PARAMS, VALIDATOR_ARGS),
)


def _nodes(context, *args, **kwargs):
    values = {a.name: LaunchConfiguration(a.name).perform(context) for a in ARGUMENTS}
    return [
        LifecycleNode(
            package="twotank_validation",
            executable="twotank_plant",
            **lifecycle_options(
                values, "twotank_plant", PLANT_PARAMS, PLANT_ARGS, fixed={"publish_clock": True}
            ),
        ),
        Node(
            package="twotank_validation",
            executable="twotank_excitation",
            **node_options(values, EXCITATION_PARAMS),
        ),
        LifecycleNode(
            package="twotank_validation",
            executable="twotank_validator",
            **lifecycle_options(values, "twotank_validator", VALIDATOR_PARAMS, VALIDATOR_ARGS),
        ),
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
