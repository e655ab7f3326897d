"""Simulated plant node for any LFT model: its excitation inputs and measured outputs on topics.

Runs :class:`twotank_validation.sim.model_plant.ModelPlant` one sample per tick (every ``ts_s``,
or when an external driver calls :meth:`ModelPlantNode.tick`): it publishes the excitation's
command of every input and the measurement of every output, each on its own topic
``topic_prefix + name`` as ``std_msgs/msg/Float64`` (model units; no header, so a validator
stamps them by their receive time, the map of
:func:`twotank_validation.sim.model_record.bag_interface_map`). All the simulation lives in the
pure module; faults (``KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S]``) and the member of the
perturbation set are fixed at start, onsets in simulated seconds since the node started.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from rclpy.node import Node
from std_msgs.msg import Float64

from twotank_validation.core.model import load_model
from twotank_validation.defaults import TS_S
from twotank_validation.errors import TwotankError
from twotank_validation.ros.params import (
    Param,
    ParameterError,
    declare,
    design_of,
    design_params,
    run_node,
)
from twotank_validation.sim import excitation
from twotank_validation.sim.model_plant import (
    ModelExcitation,
    ModelPlant,
    ModelSimConfig,
    PlantSample,
    parse_member,
    parse_model_fault,
)
from twotank_validation.sim.model_record import channel_topic, check_channel_names

MODEL_DESIGN = excitation.ExcitationDesign(
    kind="multisine", f_min_hz=0.0, f_max_hz=0.0, cutoff_hz=0.0, seed=0
)
"""A model plant's excitation by default: a multisine over the period's first line ..
``0.2 / ts_s`` (filtered noise: cutoff ``0.2 / ts_s``), seed 0 (``ModelExcitation``'s)."""

MODEL_PLANT_PARAMS = (
    Param("model", "", "model YAML file or built-in name (A, B)"),
    Param("ts_s", TS_S, "sample period (s)", 1e-6, 3600.0),
    *design_params(MODEL_DESIGN),
    Param("rms", [0.1], "RMS of each input's excitation (one value for all, or one per input)"),
    Param("offset", [0.0], "operating point of each input (one value for all, or one per input)"),
    Param("member", "nominal", "nominal | gains=G[,G...] | random[,seed=S][,scale=R]"),
    Param("noise_scale", 1.0, "noise as a fraction of what the model's weights admit", 0.0, 1e6),
    Param("noise_seed", 0, "noise seed", 0, 2**31 - 1),
    Param("faults", [""], "faults, KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S] each; '' for none"),
    Param("topic_prefix", "", "prepended to each channel name to make its topic"),
    Param(
        "self_timed", True, "publish every ts_s on a timer (false: an external driver calls tick())"
    ),
)


def _per_input(values: Sequence[float]) -> float | tuple[float, ...]:
    items = [float(v) for v in values]
    return items[0] if len(items) == 1 else tuple(items)


def config_from_parameters(values: dict[str, Any]) -> ModelSimConfig:
    """The simulation of the node's parameter values (``declare(node, MODEL_PLANT_PARAMS)``).

    Raises:
        TwotankError: A missing or bad model file, a bad setting (the message names it).
    """
    if not str(values["model"]).strip():
        raise ParameterError("parameter 'model' is empty: give a model YAML file or A or B")
    model = load_model(str(values["model"]))

    return ModelSimConfig(
        model=model,
        ts_s=float(values["ts_s"]),
        excitation=ModelExcitation(
            rms=_per_input(values["rms"]),
            offset=_per_input(values["offset"]),
            design=design_of(values),
        ),
        member=parse_member(str(values["member"])),
        noise_scale=float(values["noise_scale"]),
        noise_seed=int(values["noise_seed"]),
        faults=tuple(parse_model_fault(s) for s in values["faults"] if s.strip()),
    )


class ModelPlantNode(Node):
    """Any model's simulated plant on ROS topics, one Float64 topic per channel."""

    def __init__(self, *, name: str = "twotank_model_plant", **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        v = declare(self, MODEL_PLANT_PARAMS)
        try:
            self.config = config_from_parameters(v)
            model = self.config.model
            check_channel_names(model.input_names, model.output_names)
            self.plant = ModelPlant(self.config)
        except (TwotankError, ValueError) as err:
            raise ParameterError(f"cannot start the model plant: {err}") from err
        prefix = str(v["topic_prefix"])
        self.pub_inputs = [
            self.create_publisher(Float64, channel_topic(n, prefix), 100) for n in model.input_names
        ]
        self.pub_outputs = [
            self.create_publisher(Float64, channel_topic(n, prefix), 100)
            for n in model.output_names
        ]
        if v["self_timed"]:
            self.create_timer(self.config.ts_s, self._on_timer)

    def _on_timer(self) -> None:
        self.tick()

    def tick(self) -> PlantSample:
        """Compute the next sample, publish its inputs and outputs, and return it."""
        sample = self.plant.step()
        for pub, value in zip(self.pub_inputs, sample.u.tolist(), strict=True):
            pub.publish(Float64(data=value))
        for pub, value in zip(self.pub_outputs, sample.y.tolist(), strict=True):
            pub.publish(Float64(data=value))
        return sample


def main(args: list[str] | None = None) -> int:
    """``ros2 run twotank_validation twotank_model_plant`` entry point."""
    return run_node(ModelPlantNode, args)


if __name__ == "__main__":
    sys.exit(main())
