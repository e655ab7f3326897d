"""``twotank-validation live --plant-model FILE``: any model's plant and the validator, live.

The counterpart of :mod:`twotank_validation.ros.live` for a plant of any shape: the model
plant node (:class:`~twotank_validation.ros.model_plant_node.ModelPlantNode`, one
``std_msgs/msg/Float64`` topic per channel, ``topic_prefix + name``) and the validator node
reading those topics through the interface map the simulator writes beside a bag
(:func:`~twotank_validation.sim.model_record.bag_interface_map`: field ``data``, stamped by the
receive time), both with ``use_sim_time``. A driver owns the simulated time: for sample k it
publishes ``/clock`` = ``k ts``, waits until every node's clock shows it, lets the plant
publish sample k and waits until the validator has received every channel's message of it.
So the receive time the validator stamps each message with is exactly ``k ts``: the stamps
land on the grid without a header (the composition checks it: a sample off the grid is an
error, never a silently shifted record). Faults and the member are the plant's
(``KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S]``, onsets in simulated seconds from 0).

Channels are matched by name: every validated model must name exactly the plant's inputs
and outputs (``ChannelError``, listing both sides, before any node starts).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from twotank_validation.core.model import LFTModel, load_model
from twotank_validation.defaults import NS_PER_S, PERIOD_SAMPLES, TS_S
from twotank_validation.online import WindowReport
from twotank_validation.online import streams as itf
from twotank_validation.online.channels import ChannelError, match_channels
from twotank_validation.online.interface import InterfaceMap, input_texts, source_to_text
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.live import LiveResult, _RecordingValidator, spin_until, wait_worker
from twotank_validation.ros.model_plant_node import (
    MODEL_PLANT_PARAMS,
    ModelPlantNode,
    config_from_parameters,
)
from twotank_validation.sim.model_record import bag_interface_map, check_channel_names

__all__ = ["ModelLiveConfig", "model_interface_map", "run_model_live", "validated_models"]


@dataclass(frozen=True)
class ModelLiveConfig:
    """Settings of a composed run of a model plant and the validator.

    Attributes:
        plant_model: the plant's model (YAML path or built-in name).
        models: the models the validator judges (paths or names); empty: the plant's own.
        n_steps: samples to simulate.
        ts_s: sample period (s).
        period_samples: excitation period (samples).
        faults: the plant's faults, ``KIND:CHANNEL[=MAGNITUDE]@ONSET_S[-END_S]`` each.
        member: the member of the plant model's set (``nominal``, ``gains=...``, ``random...``).
        noise_scale: the plant's noise as a fraction of what its noise weights admit.
        seed: excitation seed.
        noise_seed: noise seed.
        topic_prefix: prepended to each channel name to make its topic.
        plant: further plant node parameters (``rms``, ``offset``, ``f_max_hz``, ...).
        validator: further validator node parameters (``periods_per_window``,
            ``settle_periods``, ``hop_samples``, ...). The live diagnosis is off unless
            ``{"diagnosis": True}`` is given here (its catalogue holds the two-tank rig's
            effects).
        record_samples: keep every aligned sample the validator consumed in the result.
    """

    plant_model: str
    models: tuple[str, ...] = ()
    n_steps: int = 4 * PERIOD_SAMPLES
    ts_s: float = TS_S
    period_samples: int = PERIOD_SAMPLES
    faults: tuple[str, ...] = ()
    member: str = "nominal"
    noise_scale: float = 1.0
    seed: int = 0
    noise_seed: int = 0
    topic_prefix: str = "plant/"
    plant: dict[str, Any] = field(default_factory=dict)
    validator: dict[str, Any] = field(default_factory=dict)
    record_samples: bool = True

    @property
    def validated(self) -> tuple[str, ...]:
        """The models the validator judges: ``models``, or the plant's own model."""
        return self.models or (self.plant_model,)

    def plant_params(self) -> dict[str, Any]:
        """The model plant node's parameters."""
        return {
            "model": self.plant_model,
            "ts_s": self.ts_s,
            "period_samples": self.period_samples,
            "faults": list(self.faults) or [""],
            "member": self.member,
            "noise_scale": self.noise_scale,
            "seed": self.seed,
            "noise_seed": self.noise_seed,
            "topic_prefix": self.topic_prefix,
            "self_timed": False,
            **self.plant,
        }


def model_interface_map(model: LFTModel, prefix: str) -> InterfaceMap:
    """The map of the model plant's topics: ``bag_interface_map`` of its channel names."""
    check_channel_names(model.input_names, model.output_names)
    return bag_interface_map(model.input_names, model.output_names, prefix)


def validated_models(config: ModelLiveConfig) -> tuple[InterfaceMap, list[LFTModel]]:
    """The plant's interface map and the validated models, their channels matched by name.

    Everything that can be wrong with the settings fails here, before any node starts: the
    plant's model file, its member and faults (``ModelSimError``), a validated model file, and
    a model naming channels the plant does not have (``ChannelError`` listing both sides).
    """
    defaults = {p.name: p.default for p in MODEL_PLANT_PARAMS}
    config_from_parameters(defaults | config.plant_params())
    plant_model = load_model(config.plant_model)
    imap = model_interface_map(plant_model, config.topic_prefix)
    models = [load_model(m) for m in config.validated]
    try:
        match_channels(
            imap.input_names,
            imap.output_names,
            models,
            source=f"the plant {plant_model.name!r} ({config.plant_model})",
        )
    except ChannelError as err:
        # the same listing of both sides; the fix is the live one (there is no map to give)
        what, _, _ = str(err).partition(" Channels are matched by name")
        raise ChannelError(
            f"{what} Channels are matched by name: validate with models that name the plant's "
            "inputs and outputs (--model FILE), or run the plant of a model with the validated "
            "model's names (--plant-model FILE)"
        ) from None
    return imap, models


def _clock_at(nodes: Sequence[Node], t_ns: int) -> bool:
    return all(n.get_clock().now().nanoseconds == t_ns for n in nodes)


def _sample_arrived(val: _RecordingValidator, k: int) -> bool:
    return min(val.received.values()) > k


def run_model_live(
    config: ModelLiveConfig,
    *,
    on_report: Callable[[WindowReport], None] | None = None,
    context: Context | None = None,
    stop: Callable[[], bool] | None = None,
) -> LiveResult:
    """Run the model plant and the validator for ``config.n_steps`` samples.

    Args:
        config: run settings.
        on_report: called (from the driver thread) with each new report as it appears.
        context: rclpy context to use (a fresh one is created and shut down otherwise).
        stop: asked before each sample; True ends the run there (the samples sent so far
            are judged and delivered; the result is ``interrupted``).

    Returns:
        Every report, the aligned samples the validator consumed (``record_samples``), the
        wall time and the aligner's counters.

    Raises:
        TwotankError: bad settings (:func:`validated_models`), before any node starts.
        RuntimeError: a message did not arrive in time, or the validator stamped a sample
            off the ``k ts`` grid.
    """
    imap, models = validated_models(config)
    own = context is None
    ctx = context or Context()
    if own:
        rclpy.init(context=ctx)
    sim = Parameter("use_sim_time", value=True)
    nodes: list[Node] = []
    try:
        plant = ModelPlantNode(
            context=ctx,
            parameter_overrides=[
                sim,
                *(Parameter(k, value=v) for k, v in config.plant_params().items()),
            ],
        )
        nodes.append(plant)
        params = {
            "ts_s": config.ts_s,
            "period_samples": config.period_samples,
            "inputs": input_texts(imap),
            "outputs": [source_to_text(s) for s in imap.outputs],
            "diagnosis": False,
            **config.validator,
        }
        val = bring_up(  # configure, then activate (the managed nodes' transitions)
            _RecordingValidator(
                record_samples=config.record_samples,
                models=models,
                context=ctx,
                parameter_overrides=[sim, *(Parameter(k, value=v) for k, v in params.items())],
            )
        )
        nodes.append(val)
        driver = Node("twotank_model_clock", context=ctx)
        nodes.append(driver)
        clock_pub = driver.create_publisher(Clock, "/clock", 10)
        executor = SingleThreadedExecutor(context=ctx)
        for n in nodes:
            executor.add_node(n)
        pubs = [*plant.pub_inputs, *plant.pub_outputs]
        if not spin_until(
            executor,
            lambda: (
                all(p.get_subscription_count() >= 1 for p in pubs)
                and clock_pub.get_subscription_count() >= 2
            ),
            10.0,
        ):
            raise RuntimeError("the plant's topics and /clock were not discovered within 10 s")
        ts_ns = round(config.ts_s * NS_PER_S)
        kept: list[WindowReport] = []

        def deliver() -> None:
            while val.new_reports:
                rep = val.new_reports.popleft()
                kept.append(rep)
                if on_report is not None:
                    on_report(rep)

        sync_every = max(1, config.period_samples // 8)
        start = time.monotonic()
        steps = 0
        for k in range(config.n_steps):
            if stop is not None and stop():
                break
            t = k * ts_ns
            clk = Clock()
            itf.set_stamp(clk.clock, t)
            clock_pub.publish(clk)
            # every node's clock at t before the plant publishes: the receive stamps are t
            if not spin_until(executor, partial(_clock_at, (plant, val), t)):
                raise RuntimeError(f"the nodes' clocks did not reach t = {t / NS_PER_S:.3f} s")
            plant.tick()
            if not spin_until(executor, partial(_sample_arrived, val, k)):
                raise RuntimeError(
                    f"validator did not receive the sample of t = {t / NS_PER_S:.3f} s"
                )
            if (k + 1) % sync_every == 0:  # the reports in simulated time (as in live.py)
                wait_worker(val)
            steps = k + 1
            deliver()
        # every sample sent has reached the validator (checked per sample)
        wait_worker(val)
        deliver()
        wall = time.monotonic() - start
        samples = list(val.samples)
        off = [s.stamp_ns for s in samples if s.stamp_ns % ts_ns]
        if off:
            raise RuntimeError(
                f"{len(off)} sample(s) stamped off the {config.ts_s:g} s grid (first at "
                f"{off[0]} ns): the receive times did not follow the simulated clock"
            )
        counters = dataclasses.asdict(val.core.counters())
        return LiveResult(
            kept, samples, wall, counters, steps=steps, interrupted=steps < config.n_steps
        )
    finally:
        for n in nodes:
            n.destroy_node()
        if own:
            rclpy.shutdown(context=ctx)
