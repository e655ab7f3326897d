"""rosbag2 bags without ROS: writing (rosbags) and simulated scenarios recorded as bags.

Imports rosbags (and mcap through it), never rclpy.
"""

from twotank_validation.bags.scenario import (
    CUSTOM_DATA_KEY,
    TOPICS,
    Scenario,
    ScenarioError,
    iter_scenario,
    load_scenario,
    scenario_from_dict,
    shipped_scenarios,
    simulate_command,
    simulate_scenario,
    write_scenario_bag,
)
from twotank_validation.bags.writer import (
    STORAGES,
    BagError,
    BagExistsError,
    BagWriteError,
    BagWriter,
    flow_command,
    fluid_pressure,
    interface_msg_dir,
    temperature_msg,
    typestore,
)

__all__ = [
    "CUSTOM_DATA_KEY",
    "STORAGES",
    "TOPICS",
    "BagError",
    "BagExistsError",
    "BagWriteError",
    "BagWriter",
    "Scenario",
    "ScenarioError",
    "flow_command",
    "fluid_pressure",
    "interface_msg_dir",
    "iter_scenario",
    "load_scenario",
    "scenario_from_dict",
    "shipped_scenarios",
    "simulate_command",
    "simulate_scenario",
    "temperature_msg",
    "typestore",
    "write_scenario_bag",
]
