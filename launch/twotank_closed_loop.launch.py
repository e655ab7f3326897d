"""Closed-loop rig: `ros2 launch twotank_validation twotank_closed_loop.launch.py`.

The simulated plant, the PI controller (which adds the excitation to its output or its
setpoints), the validator, fed the controller's `flow_cmd` and the measurements, and the
supervisor, which watches `supervisor_models` and switches the controller to its safe mode on
their alarm or silence (`control/mode`, std_msgs/String "normal"/"safe", transient-local).
Arguments: `params_file`, `namespace`, `use_sim_time` (default true: the plant owns /clock and
every node uses it), `log_level`, `autostart` (default true: launch configures and activates
the managed nodes), `models` (the validator's, comma-separated),
`supervisor_models` (the supervisor's `models`), `faults` (comma-separated fault specs, e.g.
`leak=0.06@1000`), `real_time_factor` (> 1 runs the plant's /clock faster),
`excitation_entry` (`output` or `setpoint`); an argument left empty leaves the parameter to
the params file or the node's default. The validator's input periodicity gate is opened
(`input_periodic_rtol`, the closed-loop value of twotank_validation.sim.control): closed-loop
commands are not periodic; the windows it leaves unjudged are judged with the transient term
(`transient`, its closed-loop value there). Not run by the test suite (no launch wheels on PyPI;
test/test_launch_files.py runs its logic with stand-ins); `twotank-validation live
--closed-loop` composes the same nodes in-process.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode

from launch import LaunchDescription
from twotank_validation.ros.controller_node import CONTROLLER_PARAMS
from twotank_validation.ros.launching import (
    common_arguments,
    lifecycle_options,
    parameter_arguments,
)
from twotank_validation.ros.plant_node import PLANT_PARAMS
from twotank_validation.ros.supervisor_node import SUPERVISOR_PARAMS
from twotank_validation.ros.validator_node import VALIDATOR_PARAMS
from twotank_validation.sim.control import CLOSED_LOOP_INPUT_PERIODIC_RTOL, CLOSED_LOOP_TRANSIENT

PLANT_ARGS = {"faults": "faults", "real_time_factor": "real_time_factor"}
CONTROLLER_ARGS = {"excitation_entry": "excitation_entry"}
VALIDATOR_ARGS = {"models": "models"}
SUPERVISOR_ARGS = {"supervisor_models": "models"}
ARGUMENTS = (
    *common_arguments(use_sim_time=True),
    *parameter_arguments(PLANT_PARAMS, PLANT_ARGS),
    *parameter_arguments(CONTROLLER_PARAMS, CONTROLLER_ARGS),
    *parameter_arguments(VALIDATOR_PARAMS, VALIDATOR_ARGS),
    *parameter_arguments(SUPERVISOR_PARAMS, SUPERVISOR_ARGS),
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
        LifecycleNode(
            package="twotank_validation",
            executable="twotank_controller",
            **lifecycle_options(values, "twotank_controller", CONTROLLER_PARAMS, CONTROLLER_ARGS),
        ),
        LifecycleNode(
            package="twotank_validation",
            executable="twotank_validator",
            **lifecycle_options(
                values,
                "twotank_validator",
                VALIDATOR_PARAMS,
                VALIDATOR_ARGS,
                fixed={
                    "input_periodic_rtol": CLOSED_LOOP_INPUT_PERIODIC_RTOL,
                    "transient": CLOSED_LOOP_TRANSIENT,
                },
            ),
        ),
        LifecycleNode(
            package="twotank_validation",
            executable="twotank_supervisor",
            **lifecycle_options(values, "twotank_supervisor", SUPERVISOR_PARAMS, SUPERVISOR_ARGS),
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
