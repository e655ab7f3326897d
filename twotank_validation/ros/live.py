"""``twotank-validation live``: plant, excitation and validator in one process, simulated clock.

A driver owns the simulated time: at every sample it publishes ``/clock``, lets the
excitation node publish the command for that instant, waits until the plant received it,
lets the plant publish its measurement and advance one sample, and spins the executor so the
validator gets everything. In closed loop (``LiveConfig.closed_loop``) the controller node
takes the excitation node's place: its command at each instant comes from the measurement of
the sample before (which the driver waits for), with the excitation added; the validator is
fed its ``flow_cmd`` and the measurements as in open loop, with the input periodicity gate
opened (:data:`~twotank_validation.sim.control.CLOSED_LOOP_INPUT_PERIODIC_RTOL`) and the
windows it leaves unjudged judged with the transient term
(:data:`~twotank_validation.sim.control.CLOSED_LOOP_TRANSIENT`); with
``LiveConfig.supervisor`` the supervisor node switches the controller to its safe mode on the
alarm. All the
nodes run with ``use_sim_time`` and talk over their ordinary topics (loopback DDS), so this
exercises the same code as a deployment, faster than real time and deterministically.

The live diagnosis runs in the validator's worker (``LiveConfig.inline_diagnosis``): the
simulated clock does not move on while it computes, so each answer rides on the report of
the window that started it, as in a replay of the same data; a deployment computes it in the
background and it rides on a later report (:mod:`twotank_validation.online.livediag`).

A run can be stopped between two samples (``run_live(stop=...)``, e.g. on SIGINT): what the
validator received by then is judged and delivered, and the result says it was interrupted.
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.logging_severity import LoggingSeverity
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from twotank_validation.bags.evidence import EvidenceStatus
from twotank_validation.defaults import NS_PER_S, PERIOD_SAMPLES, TS_S
from twotank_validation.online import Sample, SampleBlock, WindowReport
from twotank_validation.online import streams as itf
from twotank_validation.online.supervisor import Transition
from twotank_validation.ros.controller_node import ControllerNode
from twotank_validation.ros.excitation_node import ExcitationNode
from twotank_validation.ros.lifecycle import bring_up
from twotank_validation.ros.plant_node import PlantNode
from twotank_validation.ros.supervisor_node import SupervisorNode
from twotank_validation.ros.validator_node import DRAIN_TIMEOUT_S, ValidatorNode
from twotank_validation.sim.control import CLOSED_LOOP_INPUT_PERIODIC_RTOL, CLOSED_LOOP_TRANSIENT


@dataclass(frozen=True)
class LiveConfig:
    """Settings of a composed simulated run.

    Attributes:
        duration_s: simulated seconds to run.
        ts_s: sample period (s).
        period_samples: excitation period (samples).
        models: model names or YAML paths.
        faults: fault specs for the plant (``KIND[:CHANNEL][=MAG]@ONSET_S[-END_S]``).
        seed: plant noise seed.
        excitation_seed: excitation seed.
        validator: extra validator parameters (name -> value).
        plant: extra plant parameters.
        excitation: extra excitation parameters.
        closed_loop: run the controller node (PI loops, excitation added) instead of the
            excitation node.
        supervisor: closed loop: also run the supervisor node, which switches the
            controller to its safe mode on the watched models' alarm (docs/ros.md); its
            transitions are in the result.
        supervisor_params: extra supervisor parameters (e.g. ``models``, ``stale_after_s``).
        controller: extra controller parameters (closed loop; e.g. ``excitation_entry``,
            gains, setpoints).
        record_samples: keep every aligned sample in the result (parity checks; memory
            grows with the run).
        keep_reports: keep every report in the result. Each carries its per-bin spectrum
            (tens of kB at Ts 0.1 s), so long runs that only need ``on_report`` set False:
            the result's ``reports`` is then empty and memory does not grow with the run.
        inline_diagnosis: the validator runs the live diagnosis in its worker, before the
            report that started it goes out (module docstring); False: in its background
            executor, as deployed.
        node_info_log: the validator logs each answer of the live diagnosis (ROS log, wall
            clock stamps); False where the caller shows the answers itself.
    """

    duration_s: float = 3000.0
    ts_s: float = TS_S
    period_samples: int = PERIOD_SAMPLES
    models: tuple[str, ...] = ("A", "B")
    faults: tuple[str, ...] = ()
    seed: int = 0
    excitation_seed: int = 2
    validator: dict[str, Any] = field(default_factory=dict)
    plant: dict[str, Any] = field(default_factory=dict)
    excitation: dict[str, Any] = field(default_factory=dict)
    closed_loop: bool = False
    supervisor: bool = False
    supervisor_params: dict[str, Any] = field(default_factory=dict)
    controller: dict[str, Any] = field(default_factory=dict)
    record_samples: bool = True
    keep_reports: bool = True
    inline_diagnosis: bool = True
    node_info_log: bool = True

    @property
    def n_steps(self) -> int:
        """Samples to simulate."""
        return round(self.duration_s / self.ts_s)


@dataclass
class LiveResult:
    """What a composed run produced.

    Attributes:
        reports: every window report the validator published, in order.
        samples: the aligned samples the validator consumed (for offline parity).
        wall_s: wall time of the run.
        counters: aligner counters (duplicates, gaps, ...).
        transitions: the supervisor's mode changes (with ``LiveConfig.supervisor``).
        steps: samples simulated (all of them unless interrupted).
        interrupted: the run was stopped before its end (``run_live(stop=...)``).
        evidence: what the evidence recorder did (validator parameter ``evidence_dir``;
            None when off): the bags written on the alarms.
    """

    reports: list[WindowReport]
    samples: list[Sample]
    wall_s: float
    counters: dict[str, int]
    transitions: list[Transition] = field(default_factory=list)
    steps: int = 0
    interrupted: bool = False
    evidence: EvidenceStatus | None = None


def _overrides(values: dict[str, Any]) -> list[Parameter[Any]]:
    return [Parameter(k, value=v) for k, v in values.items()]


def spin_until(
    executor: SingleThreadedExecutor,
    cond: Callable[[], bool],
    timeout_s: float = 5.0,
    poll_s: float = 0.005,
) -> bool:
    """Spin ``executor`` until ``cond()`` holds; False if ``timeout_s`` (wall) passes first."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=poll_s)
    return True


def _command_arrived(plant: PlantNode, t_ns: int) -> bool:
    return plant.last_command_ns == t_ns


def _measured(ctl: ControllerNode, t_ns: int) -> bool:
    return all(ctl.last_measurement_ns.get(s) == t_ns for s in itf.MEASUREMENTS)


def _sample_arrived(val: ValidatorNode, k: int) -> bool:
    return min(val.received.values()) > k


def wait_worker(val: ValidatorNode) -> None:
    """Block until the validator's worker processed everything queued.

    Raises:
        RuntimeError: not within :data:`DRAIN_TIMEOUT_S`.
    """
    if not val.wait_idle(DRAIN_TIMEOUT_S):
        raise RuntimeError(
            f"the validator's worker did not catch up within {DRAIN_TIMEOUT_S:.0f} s of wall time"
        )


class _RecordingValidator(ValidatorNode):
    """Validator that also keeps every report and the aligned samples it consumed (parity)."""

    def __init__(self, *, record_samples: bool = True, **kwargs: Any) -> None:
        self.samples: list[Sample] = []
        # reports not yet handed to the driver (appended by the worker thread, drained by the
        # driver; deque append/popleft are thread-safe)
        self.new_reports: deque[WindowReport] = deque()
        self._record_samples = record_samples
        super().__init__(**kwargs)
        self.report_listeners.append(self.new_reports.append)

    def configure_node(self, values: dict[str, Any]) -> None:
        """The validator's, then the sample recorder on its core."""
        super().configure_node(values)
        if self._record_samples:
            self.core.sample_listeners.append(self._record)

    def _record(self, piece: Sample | SampleBlock) -> None:
        if isinstance(piece, SampleBlock):
            self.samples.extend(piece.samples())
        else:
            self.samples.append(piece)


def run_live(
    config: LiveConfig,
    *,
    on_report: Callable[[WindowReport], None] | None = None,
    on_transition: Callable[[Transition], None] | None = None,
    on_step: Callable[[int], None] | None = None,
    context: Context | None = None,
    attach: Callable[[Context], tuple[Sequence[Node], Callable[[int], bool]]] | None = None,
    stop: Callable[[], bool] | None = None,
) -> LiveResult:
    """Run the composition for ``config.duration_s`` simulated seconds.

    Args:
        config: run settings.
        on_report: called (from the driver thread) with each new report as it appears.
        on_transition: called (from the driver thread) with each of the supervisor's mode
            changes as it happens (``LiveConfig.supervisor``), after the reports that
            appeared by then (the one that raised it among them); the result's
            ``transitions`` holds them all again at the end.
        on_step: called (from the driver thread) with ``k`` once sample k (0-based) has
            reached the validator and the reports that appeared by then went to
            ``on_report``; e.g. to sample memory every simulated hour.
        context: rclpy context to use (a fresh one is created and shut down otherwise).
        attach: adds nodes that subscribe to the interface topics (e.g. a recorder); returns
            them and a predicate ``synced(k)``: they have every message of sample k. It is
            awaited once more for the last sample after the validator's last reports went
            to ``on_report``, so a predicate that also counts reports sees them all.
        stop: asked before each sample; True ends the run there (the samples sent so far
            are judged and delivered; the result is ``interrupted``).
    """
    if config.supervisor and not config.closed_loop:
        raise ValueError(
            "the supervisor switches the controller's mode: run it in closed loop "
            "(closed_loop=True, `live --closed-loop --supervisor`)"
        )
    own = context is None
    ctx = context or Context()
    if own:
        rclpy.init(context=ctx)
    sim = Parameter("use_sim_time", value=True)
    common = {"ts_s": config.ts_s, "period_samples": config.period_samples}
    nodes: list[Node] = []
    try:
        source = {**common, "self_timed": False, "seed": config.excitation_seed}
        exc: ExcitationNode | ControllerNode
        validator_extra: dict[str, Any] = {}
        if config.closed_loop:
            exc = bring_up(
                ControllerNode(
                    context=ctx,
                    parameter_overrides=[sim, *_overrides({**source, **config.controller})],
                )
            )
            validator_extra["input_periodic_rtol"] = CLOSED_LOOP_INPUT_PERIODIC_RTOL
            validator_extra["transient"] = CLOSED_LOOP_TRANSIENT
        else:
            exc = ExcitationNode(
                context=ctx,
                parameter_overrides=[sim, *_overrides({**source, **config.excitation})],
            )
        plant_params = {
            "ts_s": config.ts_s,
            "self_timed": False,
            "seed": config.seed,
            "faults": list(config.faults) or [""],
            **config.plant,
        }
        plant = bring_up(
            PlantNode(context=ctx, parameter_overrides=[sim, *_overrides(plant_params)])
        )
        val = _RecordingValidator(
            record_samples=config.record_samples,
            inline_diagnosis=config.inline_diagnosis,
            context=ctx,
            parameter_overrides=[
                sim,
                *_overrides(
                    {
                        **common,
                        "models": list(config.models),
                        **validator_extra,
                        **config.validator,
                    }
                ),
            ],
        )
        if not config.node_info_log:
            val.get_logger().set_level(LoggingSeverity.WARN)
        bring_up(val)  # configure, then activate (the managed nodes' transitions)
        driver = Node("twotank_clock", context=ctx)
        extra_nodes, synced = attach(ctx) if attach is not None else ((), None)
        nodes = [exc, plant, val, driver, *extra_nodes]
        supervisor = None
        if config.supervisor:
            supervisor = bring_up(
                SupervisorNode(
                    context=ctx, parameter_overrides=[sim, *_overrides(config.supervisor_params)]
                )
            )
            nodes.append(supervisor)
        n_extra = 1 if attach is not None else 0
        clock_pub = driver.create_publisher(Clock, "/clock", 10)
        executor = SingleThreadedExecutor(context=ctx)
        for n in nodes:
            executor.add_node(n)
        # discovery: wait until the intra-process publishers and subscriptions have matched
        n_measured = 1 + n_extra + (1 if config.closed_loop else 0)
        spin_until(
            executor,
            lambda: (
                exc.pub.get_subscription_count() >= 2 + n_extra
                and plant.pub_height.get_subscription_count() >= n_measured
                and plant.pub_temperature.get_subscription_count() >= n_measured
            ),
            10.0,
        )
        ts_ns = round(config.ts_s * NS_PER_S)
        kept: list[WindowReport] = []

        handed = 0  # the supervisor's transitions handed to on_transition so far

        def deliver() -> None:
            nonlocal handed
            while val.new_reports:
                rep = val.new_reports.popleft()
                if config.keep_reports:
                    kept.append(rep)
                if on_report is not None:
                    on_report(rep)
            # the supervisor runs in this thread's executor: its log grows only while the
            # driver spins, so what is new since the last call is complete here
            if supervisor is not None and on_transition is not None:
                log = supervisor.machine.log
                while handed < len(log):
                    on_transition(log[handed])
                    handed += 1

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
            exc.tick(t)
            if not spin_until(executor, partial(_command_arrived, plant, t)):
                raise RuntimeError(f"plant did not receive the command of t = {t / NS_PER_S:.1f} s")
            plant.tick(t)
            if isinstance(exc, ControllerNode) and not spin_until(
                executor, partial(_measured, exc, t)
            ):
                raise RuntimeError(
                    f"controller did not receive the measurement of t = {t / NS_PER_S:.1f} s"
                )
            # lockstep: the validator has every message of this sample before time moves on
            if synced is not None and not spin_until(executor, partial(synced, k)):
                raise RuntimeError(
                    f"attached nodes did not receive the sample of t = {t / NS_PER_S:.1f} s"
                )
            if not spin_until(executor, partial(_sample_arrived, val, k)):
                raise RuntimeError(
                    f"validator did not receive the sample of t = {t / NS_PER_S:.1f} s"
                )
            # keep the validator's worker within an eighth of a period of the simulated clock
            # (a real deployment runs in real time, where the worker keeps up; here time runs
            # as fast as the driver goes): the supervisor judges staleness on that clock, and
            # the reports (and an interrupt) must come in simulated time, not all at the end
            # when the worker lags on a loaded machine
            if (k + 1) % sync_every == 0:
                wait_worker(val)
            steps = k + 1
            deliver()
            if on_step is not None:
                on_step(k)
        # every sample sent has reached the validator (checked per sample): let the worker
        # finish them, then deliver the last reports
        wait_worker(val)
        deliver()
        interrupted = steps < config.n_steps
        if (
            synced is not None
            and steps
            and not interrupted
            and not spin_until(executor, partial(synced, steps - 1))
        ):
            raise RuntimeError("attached nodes did not receive everything by the end of the run")
        wall = time.monotonic() - start
        counters = dataclasses.asdict(val.core.counters())
        log = list(supervisor.machine.log) if supervisor is not None else []
        evidence = None
        if val.evidence is not None:  # the bag being written is closed with what came
            val.evidence.close()
            evidence = val.evidence.status()
        return LiveResult(
            kept, list(val.samples), wall, counters, log, steps, interrupted, evidence
        )
    finally:
        for n in nodes:
            n.destroy_node()
        if own:
            rclpy.shutdown(context=ctx)


def samples_as_record(samples: Sequence[Sample]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(stamps_ns, u, y)`` arrays of aligned samples."""
    stamps = np.array([s.stamp_ns for s in samples], dtype=np.int64)
    u = np.array([s.u for s in samples])
    y = np.array([s.y for s in samples])
    return stamps, u, y
