"""The model plant node publishes what the pure simulator computes (own Context, bounded spins)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

from twotank_validation.core.model import load_model
from twotank_validation.ros.model_plant_node import ModelPlantNode, main
from twotank_validation.sim import model_plant as mp

MODEL = Path(__file__).resolve().parents[1] / "data" / "models" / "three_by_two.yaml"
PARAMS = {
    "model": str(MODEL),
    "ts_s": 0.1,
    "period_samples": 64,
    "rms": [0.1, 0.2, 0.3],
    "offset": [0.5],
    "f_max_hz": 1.0,
    "seed": 4,
    "member": "random,seed=2,scale=0.8",
    "noise_seed": 9,
    "faults": ["input_gain:feed_a=0.5@3", "output_delay:temp=0.25@5"],
    "topic_prefix": "plant/",
    "self_timed": False,
}
STEPS = 120


def spin_until(ex: SingleThreadedExecutor, cond, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            return False
        ex.spin_once(timeout_sec=0.005)
    return True


def test_published_values_equal_the_pure_simulator() -> None:
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        overrides = [Parameter(k, value=v) for k, v in PARAMS.items()]
        plant = ModelPlantNode(context=ctx, parameter_overrides=overrides)
        sink = Node("sink", context=ctx)
        m = load_model(MODEL)
        names = (*m.input_names, *m.output_names)
        got: dict[str, list[float]] = {n: [] for n in names}
        for n in names:
            sink.create_subscription(
                Float64, f"plant/{n}", lambda msg, n=n: got[n].append(msg.data), 1000
            )
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(plant)
        ex.add_node(sink)
        pubs = plant.pub_inputs + plant.pub_outputs
        assert spin_until(ex, lambda: all(p.get_subscription_count() >= 1 for p in pubs))
        for _ in range(STEPS):
            plant.tick()
            ex.spin_once(timeout_sec=0.0)
        assert spin_until(ex, lambda: all(len(v) >= STEPS for v in got.values()))
        cfg = mp.ModelSimConfig(
            model=m,
            ts_s=0.1,
            excitation=mp.ModelExcitation(
                period_samples=64, rms=(0.1, 0.2, 0.3), offset=0.5, f_max_hz=1.0, seed=4
            ),
            member=mp.Member(kind="random", seed=2, scale=0.8),
            noise_seed=9,
            faults=tuple(PARAMS["faults"]),
            settle_periods=0,
            periods=2,
        )
        ref = mp.simulate_model(cfg)
        for i, n in enumerate(m.input_names):
            assert np.array_equal(got[n], ref.u[:STEPS, i])
        for i, n in enumerate(m.output_names):
            assert np.array_equal(got[n], ref.y[:STEPS, i])
        plant.destroy_node()
        sink.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "parameter 'model' is empty"),
        (["-p", f"model:={MODEL}", "-p", "faults:=['sensor_bias:pressure=1@2']"], "'pressure'"),
        (["-p", f"model:={MODEL}", "-p", "rms:=[0.1, 0.2]"], "3 channels"),
    ],
)
def test_entry_point_refuses_bad_parameters(capsys, args: list[str], message: str) -> None:
    assert main(["model_plant", "--ros-args", *args]) == 1
    assert message in capsys.readouterr().err
