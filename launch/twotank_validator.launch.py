"""Validator alone, on a real rig: `ros2 launch twotank_validation twotank_validator.launch.py`.

Remap `flow_cmd`, `height` and `temperature` to the rig's topics and set the unit
conversions (`pascal_per_unit`, `temperature_offset_c`, `temperature_span_c`) if they differ.
"""

from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description():
    """Launch description (ROS 2 launch entry point)."""
    return LaunchDescription(
        [
            DeclareLaunchArgument("latch_alarm", default_value="false"),
            Node(
                package="twotank_validation",
                executable="twotank_validator",
                parameters=[{"latch_alarm": LaunchConfiguration("latch_alarm")}],
                remappings=[
                    ("flow_cmd", "flow_cmd"),
                    ("height", "height"),
                    ("temperature", "temperature"),
                ],
            ),
        ]
    )
