"""A level that moved at steady state: a leak or a level-sensor offset, told apart.

A constant extra outflow (a leak) and a bias of the level sensor move the level's steady mean
the same way. On the two-tank rig (and in any tank model whose outlet law is linearised, as
Models A and B are) the leak does not change the level's own response: it moves the level's
equilibrium by ``-L`` times the level's steady-state gain per unit of inflow, and the level
channel alone reads exactly as a sensor offset of that size, whatever the input. Two things
tell them apart:

1. **The dynamics of the thermal balance.** A mixing tank's temperature settles with the time
   constant ``A h / F`` of the liquid it holds: a leak lowers the true level ``h`` and the
   temperature responds faster (and more strongly above its corner), a sensor offset leaves
   the plant as it was. :func:`level_moved` is the nominal re-linearised at the true level
   ``h0 + d`` with the same inputs (from the model's own matrices: an energy state ``E = h t``
   decays by ``F/(A h)``, so its diagonal scales by ``h0/(h0 + d)`` and its level entry
   ``t0 a_hh - t0 a_EE`` follows; the temperature output ``t = E/h`` reads ``1/h`` and
   ``-t0/h``; a temperature state's whole row scales by ``h0/(h0 + d)``).
   :func:`dynamics_test` fits the level change the responses show (with the dynamic effects
   one explanation chose; the diagnosis runs it for each), with its standard error
   (:func:`~twotank_validation.diagnose.fit.fit_uncertainty`), and compares the two point
   hypotheses: a leak predicts the level's mean deviation ``d``, a sensor offset 0. The
   statistic is twice the log-likelihood ratio, ``z_leak^2 - z_offset^2``; beyond the
   chi-square(1) quantile at ``alpha`` it decides for the hypothesis it favours, unless that
   one too lies beyond the matching normal quantile.
2. **The time course at the change** (only when the change is inside the recording): a sensor
   steps, the level of a tank that began to leak settles through the tank's own time constant
   (:func:`level_course`, a step and a first-order settle fitted to the level's period means,
   as the live diagnosis does).

When neither decides (the level change is small next to what the dynamics resolve, or the two
disagree), both are named with what would separate them (:class:`LevelVerdict`). A level
above what the inputs predict is not a leak (a leak only lowers it): the diagnosis tests a
level that moved down.

Pure functions over numpy arrays; no ROS.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.signal
import scipy.stats

from twotank_validation.diagnose.effects import (
    THERMAL_STATES,
    EffectSpec,
    Nominal,
    channel_time_constants,
)
from twotank_validation.diagnose.fit import BinData, fit_effects, fit_uncertainty
from twotank_validation.diagnose.inputs import Window
from twotank_validation.diagnose.kinds import EffectKind, ModelNeed
from twotank_validation.diagnose.steady import dc_gain

LEVEL = "height"
"""The output (and state) name of the tank's level."""

HOPS_PER_PERIOD = 4
"""Period means per period in the time course (the validator's default hop: a quarter)."""


# --------------------------------------------------------------------------- the tank


@dataclass(frozen=True)
class Tank:
    """Where the level and the thermal balance sit in a nominal, and the operating point.

    Attributes:
        height: index of the ``height`` state.
        thermal: index of the ``energy`` or ``temperature`` state.
        energy: the thermal state is the energy ``E = h t`` (else the temperature).
        h0: operating level (model units, > 0).
        t0: operating temperature (model units; 0 where a temperature state needs none).
        output: index of the ``height`` output.
        shows_on: index of the output that reads the thermal state (the temperature: where
            a moved level shows in the responses); the level's where none does.
    """

    height: int
    thermal: int
    energy: bool
    h0: float
    t0: float
    output: int
    shows_on: int

    @classmethod
    def of(
        cls, nominal: Nominal, outputs: Sequence[str], operating_point: Mapping[str, float]
    ) -> Tank | str:
        """The tank of a model, or why the level test does not apply to it (a sentence)."""
        if nominal.dt_s is not None:
            return "the model's nominal is discrete-time (the test moves continuous balances)"
        names = list(nominal.states)
        thermal = next((n for n in THERMAL_STATES if n in names), None)
        if LEVEL not in names or thermal is None:
            return f"the model's nominal has no {ModelNeed.TANK_STATES}"
        if LEVEL not in outputs:
            return "the model has no output named 'height'"
        h0 = operating_point.get(LEVEL)
        t0 = operating_point.get("temperature", 0.0 if thermal == "temperature" else None)
        if h0 is None or not h0 > 0 or t0 is None:
            return f"the model has no operating point ({ModelNeed.OPERATING_POINT})"
        it = names.index(thermal)
        reads = np.flatnonzero(nominal.c[:, it] != 0.0)
        h_out = list(outputs).index(LEVEL)
        return cls(
            names.index(LEVEL),
            it,
            thermal == "energy",
            float(h0),
            float(t0),
            h_out,
            int(reads[0]) if reads.size else h_out,
        )

    def thermal_time_constant(self, nominal: Nominal) -> float:
        """The thermal state's own time constant ``A h / F`` (s) in ``nominal``."""
        a = float(nominal.a[self.thermal, self.thermal])
        return -1.0 / a if a < 0 else math.inf


def level_moved(nominal: Nominal, change: float, tank: Tank) -> Nominal:
    """The nominal re-linearised at the true level ``h0 + change``, the inputs the same.

    What a constant extra outflow does to a linearised tank (module docstring, item 1). The
    level's own row is unchanged (a linearised outlet); only the thermal balance and the
    temperature output read the level. Exact against the rig's Jacobian at the leaking
    equilibrium (``test_level_moved_is_the_rigs_jacobian_with_a_leak``).
    """
    h = tank.h0 + float(change)
    r = tank.h0 / max(h, 1e-9 * tank.h0)
    a, b, c = nominal.a.copy(), nominal.b.copy(), nominal.c.copy()
    ih, it = tank.height, tank.thermal
    if tank.energy:
        old = a[it, it]
        a[it, it] = old * r
        a[it, ih] -= tank.t0 * (a[it, it] - old)
        rows = c[:, it] != 0.0  # the outputs that read t = E / h
        c[rows, it] *= r
        c[rows, ih] *= r
    else:
        a[it] *= r
        b[it] *= r
    return replace(nominal, a=a, b=b, c=c)


def inflow_gain(nominal: Nominal, tank: Tank) -> float:
    """The level's steady-state change per unit of inflow (model units).

    The mean of its column of ``G(0)`` over the inputs (each valve delivers a flow into the
    tank).
    """
    return float(np.mean(dc_gain(nominal)[tank.output]))


def leak_spec(nominal: Nominal, tank: Tank, change: float) -> EffectSpec:
    """The leak as an effect on the nominal: the level moved by ``level_change``.

    Its value comes from the means (not fitted to the dynamics); ``outflow`` is the constant
    extra outflow that moves the level by that much (:func:`inflow_gain`). It acts on the
    level; its evidence is the temperature's response (``channel``, :attr:`Tank.shows_on`).
    """
    gain = inflow_gain(nominal, tank)
    outflow = -change / gain if gain else math.nan
    h0 = tank.h0

    def apply(nom: Nominal, p: np.ndarray) -> Nominal:
        return level_moved(nom, float(p[0]), tank)

    return EffectSpec(
        EffectKind.LEAK, tank.shows_on, None, ("level_change",), (-0.9 * h0,), (h0,),
        (change, 0.0, 0.5 * change, -0.1 * h0, 0.1 * h0), (), apply, fixed={"outflow": outflow},
        acts_on=tank.output,
    )  # fmt: skip


# --------------------------------------------------------------------------- the dynamics


@dataclass(frozen=True)
class DynamicsTest:
    """The level change the dynamics show, against a leak's and a sensor offset's.

    Attributes:
        change: the level's steady deviation from the means (model units): a leak's level
            change, or the offset.
        estimate: the level change fitted to the responses (model units).
        stderr: its standard error (``inf``: the data do not determine it).
        statistic: ``z_leak^2 - z_offset^2``, twice the log-likelihood ratio of the offset
            over the leak (positive: the offset fits better).
        threshold: the statistic decides beyond this (chi-square(1) at ``alpha``), for the
            hypothesis it favours if that one lies within ``sqrt(threshold)`` standard
            errors of the estimate (the two-sided normal quantile at ``alpha``).
        with_effects: labels of the effects fitted with it.
        tau_s: the thermal time constant at the model's level and at the moved one (s).
    """

    change: float
    estimate: float
    stderr: float
    statistic: float
    threshold: float
    with_effects: tuple[str, ...] = ()
    tau_s: tuple[float, float] = (math.nan, math.nan)

    @property
    def z_offset(self) -> float:
        """The estimate from 0, in standard errors."""
        return self.estimate / self.stderr if self.stderr > 0 else math.inf

    @property
    def z_leak(self) -> float:
        """The estimate from the leak's level change, in standard errors."""
        return (self.estimate - self.change) / self.stderr if self.stderr > 0 else math.inf

    @property
    def verdict(self) -> EffectKind | None:
        """``LEAK``, ``OFFSET`` or None (the dynamics do not decide, or fit neither)."""
        if not math.isfinite(self.statistic):
            return None
        # the better hypothesis by the likelihood ratio, and not itself rejected at the
        # same level (an estimate far from both points to neither)
        crit = math.sqrt(self.threshold)
        if self.statistic > self.threshold and abs(self.z_offset) <= crit:
            return EffectKind.OFFSET
        if self.statistic < -self.threshold and abs(self.z_leak) <= crit:
            return EffectKind.LEAK
        return None

    def text(self) -> str:
        """The evidence in words."""
        t0, t1 = self.tau_s
        fitted = f" (fitted with {', '.join(self.with_effects)})" if self.with_effects else ""
        if not math.isfinite(self.stderr):
            return f"the temperature's responses do not determine the tank's level{fitted}"
        return (
            f"the temperature responds as if the tank's level were {self.estimate:+.3g} ± "
            f"{self.stderr:.2g} from the model's{fitted}: a leak predicts {self.change:+.3g} "
            f"({abs(self.z_leak):.1f} standard errors away), a sensor offset 0 "
            f"({abs(self.z_offset):.1f} away); its time constant A h/F follows the true level "
            f"({t0:.0f} s at the model's, {t1:.0f} s at the leak's)"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "level_change": num(self.estimate),
            "stderr": num(self.stderr),
            "z_leak": num(self.z_leak),
            "z_offset": num(self.z_offset),
            "statistic": num(self.statistic),
            "threshold": self.threshold,
            "with_effects": list(self.with_effects),
            "thermal_time_constant_s": [num(t) for t in self.tau_s],
            "verdict": None if self.verdict is None else self.verdict.value,
        }


def dynamics_test(  # noqa: PLR0917 - the fit's context
    nominal: Nominal,
    tank: Tank,
    change: float,
    effects: Sequence[tuple[EffectSpec, np.ndarray, str]],
    data: BinData,
    ts_s: float,
    alpha: float,
) -> DynamicsTest:
    """Fit the level change the responses show, and test a leak against a sensor offset.

    Args:
        nominal: the model's nominal.
        tank: where its level and thermal balance sit.
        change: the level's steady deviation (model units).
        effects: ``(spec, values, label)`` of the dynamic effects fitted with the level (those
            both explanations need; the values start the fit).
        data: the fit windows' excited bins.
        ts_s: sample period (s).
        alpha: level of the test.
    """
    spec = leak_spec(nominal, tank, change)  # last: its grid (the means' value, 0, ...) scanned
    specs = [*(s for s, _, _ in effects), spec]
    starts = [v for _, v, _ in effects]
    values, _ = fit_effects(nominal, specs, data, ts_s, starts or None)
    sure = fit_uncertainty(nominal, specs, data, ts_s, values)
    est, se = float(values[-1]), float(sure.stderr[-1])
    stat = ((est - change) / se) ** 2 - (est / se) ** 2 if 0 < se < math.inf else math.nan
    tau0 = tank.thermal_time_constant(nominal)
    return DynamicsTest(
        change=float(change),
        estimate=est,
        stderr=se,
        statistic=float(stat),
        threshold=float(scipy.stats.chi2.isf(alpha, 1)),
        with_effects=tuple(label for _, _, label in effects),
        tau_s=(tau0, tau0 * (tank.h0 + change) / tank.h0),
    )


# --------------------------------------------------------------------------- the time course


def period_means(
    windows: Sequence[Window], hops_per_period: int = HOPS_PER_PERIOD
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The inputs' and outputs' means over one period, every ``1/hops_per_period`` period.

    Windows that follow each other without a gap are joined, so the means run across their
    boundaries; a mean never spans a gap.

    Returns:
        ``(t_end_s (k,), u (k, nu), y (k, ny))``: the end of each mean (s, the windows'
        time), and the means (model units).
    """
    if not windows:
        return np.zeros(0), np.zeros((0, 0)), np.zeros((0, 0))
    p, ts = windows[0].period_samples, windows[0].ts_s
    hop = max(p // hops_per_period, 1)
    runs: list[list[Window]] = []
    for w in windows:
        last = runs[-1][-1] if runs else None
        if last is not None and abs(last.start_s + last.u.shape[0] * ts - w.start_s) < ts / 2:
            runs[-1].append(w)
        else:
            runs.append([w])
    t, u, y = [], [], []
    for run in runs:
        uu = np.vstack([w.u for w in run])
        yy = np.vstack([w.y for w in run])
        cu = np.vstack([np.zeros((1, uu.shape[1])), np.cumsum(uu, axis=0)])
        cy = np.vstack([np.zeros((1, yy.shape[1])), np.cumsum(yy, axis=0)])
        ends = np.arange(p, uu.shape[0] + 1, hop)
        t.append(run[0].start_s + ends * ts)
        u.append((cu[ends] - cu[ends - p]) / p)
        y.append((cy[ends] - cy[ends - p]) / p)
    return np.concatenate(t), np.vstack(u), np.vstack(y)


def mean_deviations(t_s: np.ndarray, u: np.ndarray, y: np.ndarray, nominal: Nominal) -> np.ndarray:
    """Each output's period mean less the nominal's response to the input means: (k, ny).

    A period mean is a moving average, which commutes with the plant: the output means are
    the plant's response to the input means, simulated here (scipy.signal.lsim from rest at
    the first mean, linear between means) where the means are evenly spaced and the nominal
    continuous, else its steady state ``G(0) (ū − ū_0)``. Constant while the plant is the
    nominal (the same deviation as the live diagnosis's,
    ``twotank_validation.diagnose.live_jobs.mean_deviations``).
    """
    du, dy = u - u[0], y - y[0]
    steps = np.diff(t_s)
    even = steps.size > 0 and steps[0] > 0 and np.allclose(steps, steps[0], rtol=1e-6)
    if not even or not np.any(du) or nominal.dt_s is not None:  # discrete: steady state
        return np.asarray(dy - du @ dc_gain(nominal).T)
    sys = scipy.signal.StateSpace(nominal.a, nominal.b, nominal.c, nominal.d)
    _, sim, _ = scipy.signal.lsim(sys, du, t_s - t_s[0], interp=True)
    return np.asarray(dy - np.reshape(sim, dy.shape))


def shape_fit(
    t_s: np.ndarray, dev: np.ndarray, period_s: float, tau_s: float, shape: str
) -> tuple[float, float, float]:
    """A step or a first-order settle, seen through a period mean, fitted to ``dev``.

    A step at ``t0`` averaged over a period P is ``clip((t − t0)/P, 0, 1)``; a settle with
    time constant T is ``(F(t − t0) − F(t − P − t0)) / P`` with ``F(x) = x − T (1 −
    e^{−x/T})`` for x > 0 (as the live diagnosis fits). The onset is searched on a grid of a
    tenth of a period, baseline and size by least squares.

    Returns:
        ``(rss, t0_s, size)``: the residual sum of squares, the onset (s, the time of
        ``t_s``) and the size.
    """
    t = np.asarray(t_s, dtype=float)

    def ramp(x: np.ndarray) -> np.ndarray:
        return np.clip(x / period_s, 0.0, 1.0)

    def settle(x: np.ndarray) -> np.ndarray:
        def f(z: np.ndarray) -> np.ndarray:
            z = np.maximum(z, 0.0)
            return z - tau_s * (1.0 - np.exp(-z / tau_s))

        return (f(x) - f(x - period_s)) / period_s

    form = settle if shape == "settle" else ramp
    # hand-written: a grid over the onset, linear least squares for baseline and size at
    # each (the residual is not smooth in the onset where it crosses a mean's edges)
    best = (math.inf, math.nan, 0.0)
    for t0 in np.arange(t[0] - period_s, t[-1], period_s / 10.0):
        a = np.column_stack([np.ones_like(t), form(t - t0)])
        coef, *_ = np.linalg.lstsq(a, dev, rcond=None)
        rss = float(np.sum((a @ coef - dev) ** 2))
        if rss < best[0]:
            best = (rss, float(t0), float(coef[1]))
    return best


@dataclass(frozen=True)
class Course:
    """The level's period means around a change, fitted a step and a settle.

    Attributes:
        t_s: (k,) end of each period mean (s, the windows' time).
        deviation: (k,) the level's period mean less the nominal's response to the input
            means (model units; :func:`mean_deviations`).
        period_s: the excitation period (s).
        tau_s: the level's slowest time constant (s), the settle's.
        step: ``(rss, onset_s, size)`` of the step (:func:`shape_fit`).
        settle: the same of the settle.
        threshold: the statistic decides beyond this (chi-square(1) at ``alpha``).
    """

    t_s: np.ndarray
    deviation: np.ndarray
    period_s: float
    tau_s: float
    step: tuple[float, float, float]
    settle: tuple[float, float, float]
    threshold: float

    @property
    def periods(self) -> float:
        """How many non-overlapping periods the means span.

        Their effective number: means a quarter period apart share three quarters of their
        samples.
        """
        return float((self.t_s[-1] - self.t_s[0]) / self.period_s + 1.0)

    @property
    def statistic(self) -> float:
        """``periods · ln(RSS_settle / RSS_step)``: positive when the step fits better.

        Twice the log-likelihood ratio of the two fits under Gaussian errors, counted over the
        effective number of means.
        """
        rss_step, rss_settle = max(self.step[0], 1e-300), max(self.settle[0], 1e-300)
        return self.periods * math.log(rss_settle / rss_step)

    @property
    def verdict(self) -> EffectKind | None:
        """``OFFSET`` (a step), ``LEAK`` (a settle) or None (the time course does not decide)."""
        if self.statistic > self.threshold:
            return EffectKind.OFFSET
        if self.statistic < -self.threshold:
            return EffectKind.LEAK
        return None

    def text(self) -> str:
        """The evidence in words."""
        best = self.step if self.statistic > 0 else self.settle
        ratio = math.exp(abs(self.statistic) / self.periods)
        how = (
            "stepped, as a sensor does"
            if self.statistic > 0
            else f"settled through the tank's own time constant ({self.tau_s:.0f} s), as a "
            "leaking tank does"
        )
        other = "a settle" if self.statistic > 0 else "a step"
        return (
            f"at the change (about {best[1]:.0f} s) the level's period means {how}: the fit "
            f"leaves {ratio:.1f} times less than {other} does, over {self.periods:.0f} periods"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "step_rss": self.step[0],
            "settle_rss": self.settle[0],
            "onset_s": (self.step if self.statistic > 0 else self.settle)[1],
            "level_change": (self.step if self.statistic > 0 else self.settle)[2],
            "tau_s": self.tau_s,
            "periods": self.periods,
            "statistic": self.statistic,
            "threshold": self.threshold,
            "verdict": None if self.verdict is None else self.verdict.value,
        }


def level_course(
    windows: Sequence[Window], nominal: Nominal, channel: int, alpha: float
) -> Course | None:
    """The level's time course across ``windows`` (a change among them).

    None: too few means (fewer than 3).
    """
    t, u, y = period_means(windows)
    if t.size < 3:
        return None
    dev = mean_deviations(t, u, y, nominal)[:, channel]
    w = windows[0]
    period_s = w.period_samples * w.ts_s
    taus = channel_time_constants(nominal, channel, w.ts_s)
    tau = max(taus) if taus else period_s / 10.0
    return Course(
        t_s=t,
        deviation=dev,
        period_s=period_s,
        tau_s=tau,
        step=shape_fit(t, dev, period_s, tau, "step"),
        settle=shape_fit(t, dev, period_s, tau, "settle"),
        threshold=float(scipy.stats.chi2.isf(alpha, 1)),
    )


# --------------------------------------------------------------------------- the verdict


@dataclass(frozen=True)
class LevelVerdict:
    """What moved the level: a leak, a sensor offset, or the data cannot tell.

    Attributes:
        kind: ``LEAK``, ``OFFSET``, or None (undecided: both named).
        change: the level's steady deviation (model units, from the means).
        change_std: its standard error over the windows.
        outflow: the constant extra outflow a leak of that size is (model flow units).
        dynamics: the dynamics' tests (empty: not tested, ``not_tested`` says why): the level
            fitted with the effects each explanation chose (the one that chose a stand-in
            for the other, e.g. a temperature gain for a leak's faster response, only widens
            its own interval).
        course: the time course at the change (None: no change inside the recording).
        tau_level_s: the level's own time constant (s).
        not_tested: why the dynamics were not tested, or ``""``.
    """

    kind: EffectKind | None
    change: float
    change_std: float
    outflow: float
    dynamics: tuple[DynamicsTest, ...]
    course: Course | None
    tau_level_s: float
    not_tested: str = ""

    @property
    def dynamics_verdict(self) -> EffectKind | None:
        """What the dynamics' tests decide together (None: none decides, or they disagree)."""
        votes = {t.verdict for t in self.dynamics if t.verdict is not None}
        return votes.pop() if len(votes) == 1 else None

    @property
    def shown(self) -> DynamicsTest | None:
        """The dynamics' test the text quotes: the most decisive, else the sharpest."""
        if not self.dynamics:
            return None
        decisive = [t for t in self.dynamics if t.verdict is not None]
        if decisive:
            return max(decisive, key=lambda t: abs(t.statistic))
        return min(self.dynamics, key=lambda t: t.stderr)

    def _votes(self) -> list[EffectKind]:
        course = None if self.course is None else self.course.verdict
        return [v for v in (course, self.dynamics_verdict) if v is not None]

    @property
    def conflict(self) -> bool:
        """The evidence decides for different answers.

        The time course against the dynamics, or one dynamics' test against another.
        """
        votes = {t.verdict for t in self.dynamics if t.verdict is not None}
        if self.course is not None and self.course.verdict is not None:
            votes.add(self.course.verdict)
        return len(votes) > 1

    def evidence(self) -> str:
        """What the time course and the dynamics show, in words."""
        parts = []
        if self.course is not None:
            parts.append(self.course.text())
        shown = self.shown
        if shown is not None:
            parts.append(shown.text())
        elif self.not_tested:
            parts.append(f"the dynamics were not tested ({self.not_tested})")
        if self.conflict:
            parts.append("the evidence disagrees")
        return "; ".join(parts)

    def separating(self) -> str:
        """What would tell a leak from a sensor offset here."""
        ways = ["a level reading independent of the sensor (a sight glass or a dipstick)"]
        shown = self.shown
        if shown is not None and all(math.isfinite(t) for t in shown.tau_s):
            t0, t1 = shown.tau_s
            ways.append(
                "a step of the hot valve held for a few minutes: the temperature settles with a "
                f"time constant of {t0:.0f} s if the level is where the model has it, "
                f"{t1:.0f} s if it is really {abs(self.change):.3g} "
                f"{'lower' if self.change < 0 else 'higher'} (a delay only shifts the response)"
            )
        if self.course is None:
            ways.append(
                "the transient when it began, which this recording does not hold (a sensor "
                "steps, a leaking tank settles through its own time constant, "
                f"{self.tau_level_s:.0f} s)"
            )
        return "what would separate them: " + "; or ".join(ways)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "verdict": None if self.kind is None else self.kind.value,
            "level_change": self.change,
            "level_change_std": self.change_std,
            "outflow": self.outflow,
            "dynamics": [t.to_dict() for t in self.dynamics],
            "time_course": None if self.course is None else self.course.to_dict(),
            "not_tested": self.not_tested or None,
        }


def decide(  # noqa: PLR0917 - the evidence
    change: float,
    change_std: float,
    outflow: float,
    dynamics: Sequence[DynamicsTest],
    course: Course | None,
    tau_level_s: float,
    not_tested: str = "",
) -> LevelVerdict:
    """The verdict: what the time course and the dynamics decide.

    Undecided when nothing decides or the evidence disagrees.
    """
    verdict = LevelVerdict(
        None, change, change_std, outflow, tuple(dynamics), course, tau_level_s, not_tested
    )
    votes = verdict._votes()
    kind = votes[0] if votes and not verdict.conflict else None
    return replace(verdict, kind=kind)
