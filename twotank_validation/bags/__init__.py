"""rosbag2 bags without ROS: reading, writing (rosbags), and simulated scenarios recorded as bags.

Reading: :func:`open_bag` / :class:`BagReader` (:mod:`~twotank_validation.bags.reader`, the
facade over the storage backends). Writing: :class:`BagWriter` and the interface messages
(:mod:`~twotank_validation.bags.writer`); a scenario into a bag: :func:`write_scenario_bag`
(:mod:`~twotank_validation.bags.scenario_bag`; the scenario itself is
:mod:`twotank_validation.sim.scenario`). Every failure is a :class:`BagError`
(:mod:`~twotank_validation.bags.bag_errors`).

Imports rosbags (and mcap through it), never rclpy.
"""

from twotank_validation.bags.bag_errors import (
    BagCorruptError,
    BagEmptyError,
    BagError,
    BagExistsError,
    BagFormatError,
    BagNotFoundError,
    BagWriteError,
    TopicMissingError,
    TopicTypeError,
)
from twotank_validation.bags.reader import BagReader, expected_types, open_bag
from twotank_validation.bags.records import (
    STORAGE_MCAP,
    STORAGE_MCAP_PLAIN,
    STORAGE_SQLITE3,
    BagInfo,
    BagMessage,
    FieldBatch,
)
from twotank_validation.bags.scenario_bag import (
    CUSTOM_DATA_KEY,
    TOPICS,
    simulate_command,
    write_scenario_bag,
)
from twotank_validation.bags.writer import (
    STORAGES,
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
    "STORAGE_MCAP",
    "STORAGE_MCAP_PLAIN",
    "STORAGE_SQLITE3",
    "TOPICS",
    "BagCorruptError",
    "BagEmptyError",
    "BagError",
    "BagExistsError",
    "BagFormatError",
    "BagInfo",
    "BagMessage",
    "BagNotFoundError",
    "BagReader",
    "BagWriteError",
    "BagWriter",
    "FieldBatch",
    "TopicMissingError",
    "TopicTypeError",
    "expected_types",
    "flow_command",
    "fluid_pressure",
    "interface_msg_dir",
    "open_bag",
    "simulate_command",
    "temperature_msg",
    "typestore",
    "write_scenario_bag",
]
