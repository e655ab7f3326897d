"""Whole-period windows: data-quality gates, validation against every model, the alarm.

:class:`WindowMonitor` buffers aligned samples and, at every excitation-period boundary,
validates the last ``periods_per_window`` periods against every model — but only when the
window is fit to judge (no flagged samples, input periodic for ``settle_periods`` more periods
before it, enough excitation). Otherwise the report says why and carries STALE.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from twotank_validation.core import fast
from twotank_validation.core.band import Band, excited_lines, parse_band
from twotank_validation.core.closed_loop import Controller, closed_loop_judge, controller_of
from twotank_validation.core.columns import centred, column_max_abs, column_mean
from twotank_validation.core.datum import (
    MEASURED_INPUT_RTOL,
    Datum,
    NormConvention,
    PeriodicityFinding,
    input_noise_rms,
    make_datum,
)
from twotank_validation.core.measured import input_noise_effect
from twotank_validation.core.model import LFTModel, PlantResponse
from twotank_validation.core.oppoint import OperatingPoint, combined_beta, dc_response
from twotank_validation.core.transient import (
    DcEstimate,
    LocalPolynomial,
    TransientEstimate,
    TransientMethod,
    dc_correction,
    dc_estimate,
    local_polynomial,
    scaled_noise,
    transient_estimate,
    validate_with_transient,
)
from twotank_validation.core.validate import (
    bin_response,
    check_compatible,
    pulse_moment,
    takes_closed_form,
    takes_fast_path,
    validate_beta,
    validation_band,
)
from twotank_validation.defaults import (
    MAX_RECOVERED_FRACTION,
    METHODS,
    NS_PER_S,
    PERIOD_SAMPLES,
    TS_S,
    Method,
)
from twotank_validation.errors import ModelError, TwotankError
from twotank_validation.online.alarm import (
    Alarm,
    AlarmConfig,
    AlarmState,
    reset_alarm,
    update_alarm,
)
from twotank_validation.online.aligner import Sample, SampleBlock
from twotank_validation.online.channels import Channels, match_channels
from twotank_validation.online.livediag import LiveDiagnosis
from twotank_validation.online.op_tracker import (
    SUSPENDED_NOTE,
    OperatingPointTracker,
    OpPointConfig,
    OpState,
)
from twotank_validation.online.recovery import Recovery, recover_span
from twotank_validation.online.states import (
    QUALITY_OK,
    RaisedBy,
    SampleFlag,
    WindowQuality,
    WindowState,
)
from twotank_validation.settings import check_settings, group, setting


@dataclass(frozen=True)
class MonitorConfig:
    """Settings of the online validator (all shared by the node's ROS parameters).

    Attributes:
        ts_s: sample period (s).
        period_samples: excitation period (samples).
        periods_per_window: periods validated together (a window every period).
        settle_periods: periods of periodic input required before a window is judged (the
            plant settles after the excitation started or changed).
        min_excitation_rms: a window is judged only if some input's RMS deviation reaches
            this (model units).
        input_periodic_rtol: accepted period-to-period input change, relative to its RMS.
        convention: norm convention of ||w||.
        method: solver choice passed to :func:`validate`.
        alarm: debouncing.
        max_recovered_fraction: largest fraction of a window per signal whose unusable
            samples (lost, late, non-finite; a held command) are recovered from the same phase
            of the other periods (:mod:`~twotank_validation.online.recovery`); 0: a window with
            any unusable sample is not judged.
        op: the operating-point check (:mod:`~twotank_validation.online.op_tracker`).
        hop_samples: samples between two judged windows; 0: a quarter period (one period
            where the period is not a multiple of 4). A window spans
            whole periods but may start at any sample, so a hop of a fraction of a period
            judges overlapping windows more often and a fault is seen sooner. The alarm's
            window counts are scaled to the hop so that they weigh the same span of data
            (:func:`evidence_alarm`).
        transient: the transient term of a window (:class:`~twotank_validation.core.transient.
            TransientMethod`): ``local_polynomial`` removes it (estimated from
            ``transient_half_width`` lines on each side of each bin by a polynomial of order
            ``transient_order``), and the input periodicity gate becomes the leakage left
            (``input_leakage`` < 1); ``none``: the input must repeat (``input_periodic_rtol``);
            ``auto``: a window the gate passes is judged as with ``none`` (full power), one it
            would leave unjudged (input not periodic, settling) with the term.
        transient_order: the local polynomial's order.
        transient_half_width: lines on each side of a bin.
        realisation_periods: periods of each realisation of a multi-realisation excitation
            (a new random-phase draw every ``realisation_periods`` periods, counted from the
            monitor's first sample); a window and its settling periods must lie within one
            realisation (a span across a change is ``SETTLING``); 0: one excitation
            throughout.
        band: the frequencies every model is claimed over, replacing the models' own
            (:func:`~twotank_validation.core.band.parse_band`): ``""`` each model's file's
            band (every bin without one), ``"all"`` every bin, ``"excited"``, ``"LO:HI"`` or
            ``"excited:LO:HI"`` (Hz).
        closed_loop_controller: the loop's controller, known
            (:func:`~twotank_validation.core.closed_loop.controller_of`): ``"rig"``, a
            controller file, or ``""`` (none).
    """

    ts_s: float = setting(TS_S, "sample period of the data (s)", unit="s", low=1e-3, high=60.0)
    period_samples: int = setting(
        PERIOD_SAMPLES, "excitation period (samples)", unit="samples", low=4, high=1_000_000
    )
    periods_per_window: int = setting(
        2,
        "periods validated together; a window every period",
        unit="periods",
        low=1,
        high=64,
        option="--periods-per-window",
        cli_help="excitation periods per window",
    )
    settle_periods: int = setting(
        1,
        "periods of periodic input required before a window is judged",
        unit="periods",
        low=0,
        high=64,
        option="--settle-periods",
        cli_help="periods of settled input before a window",
    )
    min_excitation_rms: float = setting(
        0.005,
        "minimum input RMS deviation (model units) to judge a window",
        unit="model units",
        low=0.0,
        high=1.0,
    )
    input_periodic_rtol: float = setting(
        1e-6, "accepted period-to-period input change relative to its RMS", low=0.0, high=1.0
    )
    convention: NormConvention = setting(
        NormConvention.POWER,
        "meaning of ||w||: power (RMS) or energy",
        choices=tuple(c.value for c in NormConvention),
        name="norm_convention",
        option="--norm",
        cli_help="norm of w",
    )
    method: str = setting(
        Method.AUTO.value, "solver: auto, closed_form, fast or sdp", choices=METHODS
    )
    alarm: AlarmConfig = group(AlarmConfig)
    max_recovered_fraction: float = setting(
        MAX_RECOVERED_FRACTION,
        "largest fraction of a window per signal whose unusable samples are recovered from "
        "the other periods (0: any unusable sample leaves the window unjudged)",
        low=0.0,
        high=0.49,
    )
    op: OpPointConfig = group(OpPointConfig, prefix="op_")
    hop_samples: int = setting(
        0,
        "samples between judged (overlapping) windows, dividing period_samples; 0: a quarter "
        "period (one period if period_samples is not a multiple of 4)",
        unit="samples",
        low=0,
        high=1_000_000_000,
        option="--hop",
        cli_help="samples between judged (overlapping) windows, dividing the period; 0: a "
        "quarter period",
    )
    band: str = setting(
        "",
        "frequencies the models are claimed over (beta and the alarm count these bins): empty "
        "for each model file's band (every bin without one), all, excited (the command's "
        "excited lines), LO:HI in Hz, or excited:LO:HI",
        unit="Hz",
        option="--band",
        cli_help="frequencies the models are claimed over: all, excited, LO:HI (Hz) or "
        "excited:LO:HI; default: each model file's band, else every bin",
    )

    closed_loop_controller: str = setting(
        "",
        "the loop's controller, known: rig (the rig's PI pair) or a controller YAML file "
        "(pi_pair or a discrete lti); windows are then judged on the closed-loop formulation "
        "(needs the transient term, docs/theory.md section 21); empty: the direct one",
        option="--closed-loop-controller",
        cli_help="the loop's controller, known: rig or a controller YAML file (needs "
        "--transient local_polynomial); default: none",
    )

    realisation_periods: int = setting(
        0,
        "periods of each realisation of a multi-realisation excitation (each a new random "
        "draw; counted from the first sample): a window and its settling periods lie within "
        "one realisation, a change of realisation is settling, not a non-periodic input; 0: "
        "one excitation throughout",
        unit="periods",
        low=0,
        high=1_000_000,
        option="--realisation-periods",
        cli_help="periods of each realisation of a multi-realisation excitation (from the "
        "recording's excitation design where it has one); 0: one excitation throughout",
    )

    transient: TransientMethod = setting(
        TransientMethod.NONE,
        "the transient term of a window: none (the input must repeat and the plant settle) "
        "or local_polynomial (estimated from the lines around each bin and removed; the "
        "input periodicity gate then measures the leakage left, docs/theory.md), or auto "
        "(none where the gate passes, local_polynomial where it would leave the window "
        "unjudged)",
        choices=tuple(c.value for c in TransientMethod),
        option="--transient",
        cli_help="the transient term of a window: none, local_polynomial (windows "
        "spanning a change are judged), or auto (the term only where the gate fails)",
    )
    transient_order: int = setting(
        2, "order of the transient term's local polynomial", low=0, high=6
    )
    transient_half_width: int = setting(
        2,
        "lines on each side of a bin the transient term is estimated from",
        unit="lines",
        low=1,
        high=32,
    )

    def __post_init__(self) -> None:
        check_settings(self)
        if self.transient != TransientMethod.NONE:
            local_polynomial(  # a fit the window cannot hold fails here, naming the fix
                self.window_samples,
                self.periods_per_window,
                self.transient_order,
                self.transient_half_width,
            )
        self.band_of()  # a band that does not parse fails here, naming the forms
        span = self.periods_per_window + self.settle_periods
        if self.realisation_periods and self.realisation_periods < span:
            raise ValueError(
                f"realisation_periods = {self.realisation_periods} is shorter than a window "
                f"and its settling ({self.periods_per_window} + {self.settle_periods} "
                "periods): no window would lie within one realisation; record longer "
                "realisations or use fewer periods per window"
            )
        if not (
            self.hop_samples == 0
            or (
                0 < self.hop_samples <= self.period_samples
                and self.period_samples % self.hop_samples == 0
            )
        ):
            raise ValueError(
                f"hop_samples must divide period_samples = {self.period_samples} (e.g. "
                f"{self.period_samples // 4} for a quarter period), or be 0 for the default; "
                f"found {self.hop_samples}"
            )

    def band_of(self, model: LFTModel | None = None) -> Band | None:
        """The band ``model`` is judged over: :attr:`band` where given, else the model's own."""
        if not self.band:
            return model.band if model is not None else None
        return parse_band(self.band)

    def banded(self, model: LFTModel) -> LFTModel:
        """``model`` with the band it is judged over (itself where that is its own)."""
        band = self.band_of(model)
        return model if band == model.band else replace(model, band=band)

    @property
    def window_samples(self) -> int:
        """Samples per validated window."""
        return self.periods_per_window * self.period_samples

    @property
    def hop(self) -> int:
        """Samples between two judged windows (``hop_samples``, or a quarter period)."""
        if self.hop_samples:
            return self.hop_samples
        return self.period_samples // 4 if self.period_samples % 4 == 0 else self.period_samples

    @property
    def span_samples(self) -> int:
        """Samples that must be clean and periodic before a window is judged."""
        return (self.periods_per_window + self.settle_periods) * self.period_samples


@dataclass(frozen=True)
class WindowReport:
    """One model's verdict on one window (everything the ROS ValidationReport carries).

    Attributes:
        model: model name.
        start_ns: stamp of the first sample of the window (ns).
        end_ns: stamp of the last sample (ns).
        n_periods: periods in the window.
        n_samples: samples in the window.
        judged: the window was fit to judge.
        data_quality: ``"ok"`` or why it was not judged; a judged window's text starts with
            ``"ok"`` and goes on with what was recovered and, one ``"; warning: ..."`` each,
            the :attr:`warnings`. For humans: :attr:`quality` is the same state typed.
        beta: total min ||w|| over the window's bins: the dynamics (NaN when not judged).
        beta_lower: general solver's certified lower bound (NaN for the closed form).
        beta_upper: general solver's witness upper bound (NaN for the closed form).
        margin: ``1 - beta``.
        invalidated: raw verdict of the window (``beta_total > 1``): what the alarm debounces.
        alarm: debounced alarm after this window.
        convention: norm convention name.
        solver: solver that ran (empty when not judged).
        freqs_hz: (n_bins,) float.
        w_min: (n_bins,) float.
        compute_time_s: wall time of the validation.
        warnings: what makes a judged window's verdict weaker than it looks, in words
            (``ValidationResult.warnings`` of :func:`validate`, e.g. a transient still
            decaying in the window); empty when there is nothing to say, and for a window
            not judged (``data_quality`` says why).
        beta_op: the operating point's min ``|W(0)|``: the window's input and output means
            against the reference (:mod:`~twotank_validation.online.op_tracker`); NaN where it
            was not checked (no reference yet, a transient, the check off, not judged).
        beta_total: ``sqrt(beta² + beta_op²)`` (``beta`` where the operating point was not
            checked; NaN when not judged).
        raised_by: what made the window invalidating (:class:`~.states.RaisedBy`, its text
            ``"dynamics"``, ``"operating point"``, ``"dynamics and operating point"``: both,
            or each below 1 and together above); ``RaisedBy.NONE`` (``""``) when it is valid
            or not judged.
        operating_point: the reference's state (``commissioning``, ``given``,
            ``commissioned``, ``moved by a setpoint change``, ``suspended``, ``off``) and,
            after a colon, why the window was not checked or what happened.
        op_state: the reference's state typed (:class:`~.op_tracker.OpState`); None where no
            tracker stands behind the report. ``SUSPENDED``: the model was invalidated before
            a reference was set, the operating point goes unchecked, and the alarm stays at
            least WARN.
        diagnosis: the live diagnosis in force at this window (the most likely effect behind
            the alarm, :mod:`~twotank_validation.online.livediag`); None before one is ready,
            while the alarm is not ERROR, and without a diagnoser.
        quality: the window's state typed (:class:`~.states.WindowQuality`): judged (ok,
            recovered) or why not, with the kind of the first unusable sample.
        findings: the periodicity findings among the :attr:`warnings`, typed
            (:class:`~twotank_validation.core.datum.PeriodicityFinding`: ``INPUT_NOT_PERIODIC``
            only where the input's leakage may decide the verdict, a transient, ...).
        input_leakage: how far the input's change from period to period may move β
            (``ValidationResult.input_leakage``; 0 for a periodic input, NaN when not
            judged): the warning ``INPUT_NOT_PERIODIC`` is given where it reaches ``|1 - β|``.
        input_change: what the input periodicity gate measured: the largest change of an
            input from one period to the next over the window and its settling periods,
            relative to that input's RMS (``input_periodic_rtol`` bounds it); NaN where the
            gate did not run (unusable samples, settling). Commanded inputs only (a
            measured input's change is its noise: :attr:`input_noise`).
        input_noise: the largest noise of a measured input (the interface map's ``kind:
            measured``), the RMS of its period-to-period spread over the window and its
            settling periods relative to its RMS (``MEASURED_INPUT_RTOL`` bounds it); 0
            without measured inputs, NaN where the gate did not run.
        input_noise_effect: how far the noise left in the measured inputs (averaged over
            the window's periods) may move β, through the nominal and the noise channels
            (:func:`~twotank_validation.core.measured.input_noise_effect`, docs/theory.md);
            0 without measured inputs, NaN when not judged. A warning is given where it
            reaches ``|1 - β|``.
        beta_outside: the same total as ``beta`` over the bins outside the model's band
            (``ValidationResult.beta_outside``); NaN without a band and when not judged.
        lines_outside: the bins outside the band that carry most of it, ``(Hz, share)``
            (``ValidationResult.lines_outside``); empty without a band.
        noise_beta: the β the window's noise alone is expected to cost under the model's
            noise weights (``ValidationResult.noise_beta``, from the period-to-period
            spread, docs/theory.md §13); NaN when not judged or with one period. A warning
            is given above 0.9: the noise weights alone use most of β's budget.
        noise_floor: (n_bins,) float, its per-bin terms: the min ``||W(n)||`` the window's
            noise alone is expected to cost at each bin of ``freqs_hz``
            (``ValidationResult.noise_floor``, comparable to ``w_min``; over the band's bins
            ``noise_beta² = Σ_n b_n noise_floor(n)²``); NaN with one period, empty when not
            judged.
        excited: (n_bins,) bool, the bins of ``freqs_hz`` the command excites (the harmonics
            with power, :func:`~twotank_validation.core.band.excited_lines`: the band's
            ``excited``, the report figures' markers); empty when not judged.
    """

    model: str
    start_ns: int
    end_ns: int
    n_periods: int
    n_samples: int
    judged: bool
    data_quality: str
    beta: float
    beta_lower: float
    beta_upper: float
    margin: float
    invalidated: bool
    alarm: Alarm
    convention: str
    solver: str
    freqs_hz: np.ndarray
    w_min: np.ndarray
    compute_time_s: float
    warnings: tuple[str, ...] = ()
    beta_op: float = math.nan
    beta_total: float = math.nan
    raised_by: RaisedBy = RaisedBy.NONE
    operating_point: str = ""
    op_state: OpState | None = None
    diagnosis: LiveDiagnosis | None = None
    quality: WindowQuality = QUALITY_OK
    findings: tuple[PeriodicityFinding, ...] = ()
    input_leakage: float = math.nan
    input_change: float = math.nan
    input_noise: float = math.nan
    input_noise_effect: float = math.nan
    beta_outside: float = math.nan
    lines_outside: tuple[tuple[float, float], ...] = ()
    noise_beta: float = math.nan
    noise_floor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    excited: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))


def raised_by(beta: float, beta_op: float, beta_total: float) -> RaisedBy:
    """Which part of the verdict made a window invalidating (``NONE`` if it is valid)."""
    if not beta_total > 1.0:
        return RaisedBy.NONE
    if beta > 1.0:
        return RaisedBy.DYNAMICS if not beta_op > 1.0 else RaisedBy.BOTH
    if beta_op > 1.0:
        return RaisedBy.OPERATING_POINT
    return RaisedBy.BOTH


def evidence_alarm(alarm: AlarmConfig, hops_per_period: int) -> AlarmConfig:
    """The debounce for windows ``hops_per_period`` times a period, weighing the same data.

    ``alarm_windows`` invalidating windows a period apart span ``alarm_windows − 1`` periods
    beyond the first window. With a hop of ``1/q`` period the same span holds
    ``(alarm_windows − 1) q + 1`` windows, and ERROR needs all of them invalidating: the
    event contains the one-per-period rule's event for that alignment (its first and last
    window are that rule's two), so a hop never makes a false alarm likelier than the
    period rule at the same start (docs/theory.md §9). Clearing is scaled the same way.
    """
    if hops_per_period == 1:
        return alarm
    return replace(
        alarm,
        alarm_windows=(alarm.alarm_windows - 1) * hops_per_period + 1,
        clear_windows=(alarm.clear_windows - 1) * hops_per_period + 1,
    )


def verdict_text(rep: WindowReport) -> str:
    """A judged window's verdict in words: β, β_op where checked, and what invalidated it.

    ``"beta 0.502 (margin +0.498), operating point beta_op 5.02: INVALIDATED by the
    operating point"``.
    """
    op = f", operating point beta_op {rep.beta_op:.3g}" if math.isfinite(rep.beta_op) else ""
    verdict = f"INVALIDATED by the {rep.raised_by}" if rep.invalidated else "not invalidated"
    if rep.invalidated and rep.raised_by == RaisedBy.BOTH:
        verdict = "INVALIDATED by the dynamics and the operating point"
    if rep.op_state is OpState.SUSPENDED:
        verdict += f"; operating point not checked ({SUSPENDED_NOTE})"
    return f"beta {rep.beta:.3f} (margin {rep.margin:+.3f}){op}: {verdict}"


class WindowMonitor:
    """Buffer aligned samples; every period, validate the last window against each model.

    Args:
        config: monitor settings.
        models: models to validate.
        channels: the samples' channels and each model's place among them, matched by name
            (:func:`~twotank_validation.online.channels.match_channels`); default: the first
            model's inputs and outputs, which every model must then name.
        measured_inputs: names of the inputs logged by a sensor (the interface map's
            ``kind: measured``): their gate tolerates their own noise and the datum averages
            them over the periods (docs/theory.md, "Measured inputs").

    Raises:
        ModelError: no model, a model without noise channels, or a measured input that is
            not one of the inputs.
        ChannelError: a model's channels do not match the samples' by name.
    """

    def __init__(
        self,
        config: MonitorConfig,
        models: Sequence[LFTModel],
        channels: Channels | None = None,
        measured_inputs: Collection[str] = (),
        controller: Controller | None = None,
    ) -> None:
        if not models:
            raise ModelError("the monitor needs at least one model")
        self.config = config
        self.models = tuple(config.banded(m) for m in models)
        if channels is None:
            first = self.models[0]
            channels = match_channels(
                first.input_names,
                first.output_names,
                self.models,
                source=f"model {first.name}",
            )
        self.channels = channels
        nu, ny = channels.n_inputs, channels.n_outputs
        unknown = sorted(set(measured_inputs) - set(channels.input_names))
        if unknown:
            raise ModelError(
                f"measured inputs {unknown} are not among the inputs "
                f"{list(channels.input_names)}: mark an input of the interface map measured"
            )
        self._measured = np.array([n in measured_inputs for n in channels.input_names], bool)
        for m in self.models:
            if m.nw == 0:
                raise ModelError(
                    f"model {m.name} has no noise channels: measured data, which always hold "
                    "noise, would invalidate it in every window whatever its plant; add a "
                    "noise section with the sensors' noise to its file"
                )
        self.n_inputs, self.n_outputs = nu, ny
        # names of the aligner's flags (outputs) and of the signals in recovery reasons
        self._output_names = channels.output_names
        self._signal_names = (*channels.input_names, *channels.output_names)
        self._select = {m.name: channels.models[m.name] for m in self.models}
        self._measured_of = {  # per model, in its own input order; None: all commanded
            m.name: self._measured[list(self._select[m.name].inputs)]
            if self._measured.any()
            else None
            for m in self.models
        }
        cap = self._cap = config.span_samples
        self._period = config.period_samples
        self._hop = config.hop
        self._alarm = evidence_alarm(config.alarm, config.period_samples // config.hop)
        self._weight = config.hop / config.period_samples  # of a window, in the evidence
        self._window = config.window_samples
        self._u = np.zeros((cap, nu))
        self._y = np.zeros((cap, ny))
        self._stamp = np.zeros(cap, dtype=np.int64)
        self._flag: list[str | None] = [None] * cap
        self._count = 0
        self._last_index: int | None = None
        # everything that depends only on the models and the settings is computed now, not in
        # the first window (whose report would wait for it), and memoised on the model (a
        # validator built again for the same models repeats none of it): P at the window's
        # bins with the solver's route on it, and where the closed form does not run, the
        # leakage bound's pulse-response moment and the fast path's compiled kernel
        self._responses: dict[str, PlantResponse] = {
            m.name: bin_response(m, config.window_samples, config.ts_s) for m in self.models
        }
        for m in self.models:
            resp = self._responses[m.name]
            if takes_closed_form(resp, config.method):
                continue
            pulse_moment(m, config.ts_s)
            if takes_fast_path(resp, config.method):
                fast.warm_up(resp)
        # the transient term's estimate and the noise channels it scales: per window settings
        self._lpm: LocalPolynomial | None = None
        self._est: dict[str, TransientEstimate] = {}
        self._scaled: dict[str, PlantResponse] = {}
        self._dc: dict[str, DcEstimate] = {}  # the term at DC: the operating point's check
        if config.transient != TransientMethod.NONE:
            self._lpm = local_polynomial(
                config.window_samples,
                config.periods_per_window,
                config.transient_order,
                config.transient_half_width,
            )
            self._est = {
                m.name: transient_estimate(self._lpm, m, config.ts_s, config.window_samples)
                for m in self.models
            }
            self._scaled = {
                name: scaled_noise(resp, self._est[name].noise_scale)
                for name, resp in self._responses.items()
            }
            self._dc = {
                name: dc_estimate(
                    est.den,
                    config.periods_per_window,
                    config.transient_order,
                    config.transient_half_width,
                )
                for name, est in self._est.items()
            }
        # the loop's controller known: the closed-loop formulation (docs/theory.md §21)
        if controller is None:
            controller = controller_of(config.closed_loop_controller, config.ts_s)
        self._closed = closed_loop_judge(
            controller, self._lpm, self.models, config.periods_per_window
        )
        self.alarms: dict[str, AlarmState] = {m.name: AlarmState() for m in self.models}
        self.operating_points: dict[str, OperatingPointTracker] = {
            m.name: OperatingPointTracker(
                m,
                config.op,
                config.ts_s,
                config.window_samples,
                convention=config.convention,
                method=config.method,
                spacing_ns=round(config.period_samples * config.ts_s * NS_PER_S),
            )
            for m in self.models
        }

    def reset_buffer(self) -> None:
        """Forget buffered samples (after a clock reset); alarm states are kept."""
        self._count = 0
        self._last_index = None

    def reset_alarms(self) -> None:
        """Clear latched alarms of every model."""
        self.alarms = {k: reset_alarm(v) for k, v in self.alarms.items()}

    def set_alarm(self, alarm: AlarmConfig) -> None:
        """Debounce the next windows with ``alarm`` (the alarm states so far are kept)."""
        self.config = replace(self.config, alarm=alarm)
        self._alarm = evidence_alarm(alarm, self.config.period_samples // self.config.hop)

    def reset_operating_points(self) -> None:
        """Forget every model's reference operating point (the given one again, or commission)."""
        for tracker in self.operating_points.values():
            tracker.reset()

    def push(self, sample: Sample) -> list[WindowReport]:
        """Add one aligned sample; returns one report per model at each period boundary."""
        index = sample.index
        if self._last_index is not None and index != self._last_index + 1:
            # the aligner restarted (clock reset): periods restart from here
            self._count = 0
        self._last_index = index
        count = self._count
        pos = count % self._cap
        self._u[pos] = sample.u
        self._y[pos] = sample.y
        self._stamp[pos] = sample.stamp_ns
        self._flag[pos] = sample.flag
        self._count = count = count + 1
        if count % self._hop or count < self._window:
            return []
        return self._evaluate()

    def push_block(
        self, block: SampleBlock, on_report: Callable[[WindowReport], None] | None = None
    ) -> list[WindowReport]:
        """Add consecutive samples at once: the same reports as pushing them one by one.

        ``on_report`` is called with each report as soon as its window is evaluated, while
        :meth:`last_window` still returns that window.
        """
        m = len(block)
        if m == 0:
            return []
        if self._last_index is not None and block.first_index != self._last_index + 1:
            self._count = 0  # the aligner restarted (clock reset)
        self._last_index = block.first_index + m - 1
        out: list[WindowReport] = []
        cap, period = self._cap, self._hop
        i = 0
        while i < m:
            count = self._count
            take = min(m - i, period - count % period)
            pos = count % cap
            while take:  # at most two pieces: up to the end of the ring, then from its start
                piece = min(take, cap - pos)
                self._u[pos : pos + piece] = block.u[i : i + piece]
                self._y[pos : pos + piece] = block.y[i : i + piece]
                self._stamp[pos : pos + piece] = block.stamps_ns[i : i + piece]
                self._flag[pos : pos + piece] = block.flags[i : i + piece]
                i += piece
                take -= piece
                count += piece
                pos = 0
            self._count = count
            if count % period == 0 and count >= self._window:
                reports = self._evaluate()
                out.extend(reports)
                if on_report is not None:
                    for rep in reports:
                        on_report(rep)
        return out

    def measured_of(self, model: str) -> np.ndarray | None:
        """(nu,) bool, the model's measured inputs in its own input order; None: all commanded."""
        return self._measured_of[model]

    def last_window(self, model: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(stamps_ns, u, y)`` of the most recent window: (n,), (n, nu), (n, ny) copies.

        Args:
            model: a model's name: its inputs and outputs in its own order; None: every
                channel in the samples' order.
        """
        u, y, stamps, _ = self._ordered(min(self._count, self.config.window_samples))
        if model is not None:
            u, y = self._select[model].select(u, y)
        return stamps.copy(), u.copy(), y.copy()

    def _ordered(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str | None]]:
        """Last ``n`` buffered samples in time order (copies)."""
        cap = self._cap
        start = (self._count - n) % cap
        if start + n <= cap:  # one piece of the ring
            sl = slice(start, start + n)
            return self._u[sl].copy(), self._y[sl].copy(), self._stamp[sl].copy(), self._flag[sl]
        head, tail = slice(start, cap), slice(0, start + n - cap)  # two pieces
        return (
            np.concatenate([self._u[head], self._u[tail]]),
            np.concatenate([self._y[head], self._y[tail]]),
            np.concatenate([self._stamp[head], self._stamp[tail]]),
            self._flag[head] + self._flag[tail],
        )

    def _recovered(self, u: np.ndarray, y: np.ndarray, flags: list[str | None]) -> Recovery:
        """The span (time order) with its recoverable samples filled in (or why not)."""
        cfg = self.config
        span = len(u)
        return recover_span(
            u,
            y,
            flags,
            period=cfg.period_samples,
            window=min(span, cfg.window_samples),
            max_fraction=cfg.max_recovered_fraction,
            names=self._signal_names,
            output_names=self._output_names,
            rtol=cfg.input_periodic_rtol,
        )

    def _settling(self) -> str | None:
        """Why the span is still settling (too few periods, or a new realisation); None: not."""
        cfg = self.config
        L = cfg.period_samples
        if self._count < cfg.span_samples:
            return (
                f"settling: {cfg.settle_periods} period(s) of periodic input are needed "
                f"before the window ({self._count // L - cfg.periods_per_window} so far)"
            )
        if cfg.realisation_periods:
            # samples of the current realisation seen so far (a whole one at its last sample)
            into = (self._count - 1) % (cfg.realisation_periods * L) + 1
            if into < cfg.span_samples:
                return (
                    f"settling: a new realisation of the excitation started {into / L:.3g} "
                    f"period(s) ago; the window and {cfg.settle_periods} settling period(s) "
                    "must lie within one realisation"
                )
        return None

    def _gate(
        self, rec: Recovery, flags: list[str | None]
    ) -> tuple[str, WindowQuality, float, float, str | None]:
        """:meth:`_quality` with the transient term's setting; last: why the term judges.

        ``auto``: the window is judged without the term where the gate passes; where it
        would leave the window unjudged because the input does not repeat or the plant is
        settling (findings of the samples and the clock, never of a model: every model on
        the window takes the same test), the gate is asked again as with the term, and the
        last item says what the first gate found (None: the term is not used).
        """
        method = self.config.transient
        if method == TransientMethod.NONE:
            return (*self._quality(rec, flags), None)
        if method == TransientMethod.LOCAL_POLYNOMIAL:
            return (*self._quality(rec, flags, term=True), "")
        first = self._quality(rec, flags)
        if first[1].state not in (WindowState.SETTLING, WindowState.INPUT_NOT_PERIODIC):
            return (*first, None)
        with_term = self._quality(rec, flags, term=True, settle=False)
        if with_term[1].state is not WindowState.OK:
            return (*with_term, None)
        return (*with_term, first[0])

    def _quality(
        self, rec: Recovery, flags: list[str | None], *, term: bool = False, settle: bool = True
    ) -> tuple[str, WindowQuality, float, float]:
        """Whether the span can be judged: text, typed state and what the input gate measured.

        The state is ``OK`` or why not; the measures are ``WindowReport.input_change`` and
        ``WindowReport.input_noise``. ``term``: the window is judged with the transient term
        (a commanded input need not repeat); ``settle``: the settling periods are asked for.
        """
        cfg = self.config
        L = cfg.period_samples
        span = len(flags)
        if rec.reason is not None:
            bad = [f for f in flags if f is not None]
            first = f"; first: {bad[0]}" if bad else ""
            n_bad = max(len(bad), int(rec.recovered.sum()))
            head = f"{n_bad} unusable sample(s) in the window or its settling periods"
            unusable = WindowQuality(
                WindowState.UNUSABLE_SAMPLES, SampleFlag.of(bad[0] if bad else None)
            )
            if cfg.max_recovered_fraction <= 0.0:
                return head + first, unusable, math.nan, math.nan
            return f"{head}: {rec.reason}{first}", unusable, math.nan, math.nan
        u = rec.u
        if settle and (settling := self._settling()) is not None:
            return settling, WindowQuality(WindowState.SETTLING), math.nan, math.nan
        rms = np.sqrt(column_mean(centred(u, column_mean(u)) ** 2))
        change = column_max_abs(u[L:] - u[:-L]) if span > L else np.zeros(self.n_inputs)
        meas = self._measured
        relative = np.where(meas, 0.0, change / np.maximum(rms, 1e-12))
        measured = float(np.max(relative)) if relative.size else 0.0
        if term:  # the leakage left after the transient term is the gate
            relative = np.zeros_like(relative)
        noise = np.zeros(self.n_inputs)
        if meas.any() and span >= 2 * L:
            whole = u[span % L :]
            noise = np.where(meas, input_noise_rms(whole, L) / np.maximum(rms, 1e-12), 0.0)
        noise_max = float(np.max(noise)) if noise.size else 0.0
        if np.any(relative > cfg.input_periodic_rtol) or noise_max > MEASURED_INPUT_RTOL:
            return (
                _not_periodic_text(relative > cfg.input_periodic_rtol, change, noise),
                WindowQuality(WindowState.INPUT_NOT_PERIODIC),
                measured,
                noise_max,
            )
        win_u = u[-cfg.window_samples :]
        win_rms = np.sqrt(column_mean(centred(win_u, column_mean(win_u)) ** 2))
        if float(np.max(win_rms)) < cfg.min_excitation_rms:
            return (
                (
                    f"too little excitation: input RMS {np.array2string(win_rms, precision=4)} "
                    f"below min_excitation_rms = {cfg.min_excitation_rms}"
                ),
                WindowQuality(WindowState.TOO_LITTLE_EXCITATION),
                measured,
                noise_max,
            )
        return "ok", QUALITY_OK, measured, noise_max

    def _evaluate(self) -> list[WindowReport]:
        cfg = self.config
        n = cfg.window_samples
        # the window and its settling periods, once (the window is their last n samples)
        u_span, y_span, stamps, flags = self._ordered(min(self._count, cfg.span_samples))
        start_ns, end_ns = int(stamps[-n]), int(stamps[-1])
        rec = self._recovered(u_span, y_span, flags)
        quality, reason, input_change, input_noise, term = self._gate(rec, flags)
        u, y = rec.u[-n:], rec.y[-n:]
        judged_quality, judged_reason = "ok", QUALITY_OK
        if term:  # auto: the gate's finding, said on the judged window
            judged_quality = f"ok; judged with the transient term ({term})"
        if rec.recovered.any():
            judged_quality = judged_quality + (
                f"; recovered {int(rec.recovered.sum())} sample(s) from the other periods "
                f"({rec.summary(self._signal_names)})"
            )
            judged_reason = WindowQuality(WindowState.RECOVERED)
        # one datum per distinct channel selection: the samples' order for every model that
        # takes all channels in it (the common case), the model's own order otherwise
        data: dict[tuple[tuple[int, ...], tuple[int, ...]], Datum | tuple[str, WindowQuality]]
        data = {}
        reports = []
        for model in self.models:
            pick = self._select[model.name]
            key = (pick.inputs, pick.outputs)
            if reason.state is WindowState.OK and key not in data:
                try:
                    data[key] = make_datum(
                        *pick.select(u, y),
                        ts_s=cfg.ts_s,
                        period_samples=cfg.period_samples,
                        convention=cfg.convention,
                        measured=self._measured_of[model.name],
                    )
                except TwotankError as err:
                    data[key] = (
                        f"datum rejected: {err}",
                        WindowQuality(WindowState.DATUM_REJECTED),
                    )
            datum = data.get(key, (quality, reason))
            if isinstance(datum, tuple):
                unjudged = self._unjudged(model.name, start_ns, end_ns, *datum)
                reports.append(
                    replace(unjudged, input_change=input_change, input_noise=input_noise)
                )
                continue
            check_compatible(datum, model)
            t0 = time.perf_counter()
            if term is None:
                res = validate_beta(
                    datum, model, method=cfg.method, response=self._responses[model.name]
                )
            else:
                judge = validate_with_transient if self._closed is None else self._closed
                res, rho = judge(
                    datum,
                    model,
                    self._est[model.name],
                    method=cfg.method,
                    response=self._responses[model.name],
                    scaled=self._scaled[model.name],
                )
                if not rho < 1.0:
                    unjudged = self._unjudged(
                        model.name,
                        start_ns,
                        end_ns,
                        transient_gate_text(rho),
                        WindowQuality(WindowState.INPUT_NOT_PERIODIC),
                    )
                    reports.append(
                        replace(
                            unjudged,
                            input_change=input_change,
                            input_noise=input_noise,
                            input_leakage=rho,
                        )
                    )
                    continue
            steady = not datum.periodicity.transient_suspected
            dc = self._dc.get(model.name)
            op = self.operating_points[model.name].observe(
                OperatingPoint(datum.u_bias, datum.y_bias),
                steady=steady,
                end_ns=end_ns,
                invalidated=res.beta > 1.0,
                transient=None
                if steady or dc is None
                else dc_correction(
                    dc, datum, self._responses[model.name], dc_response(model, cfg.ts_s)
                ),
            )
            op_term = not steady and op.check is not None
            elapsed = time.perf_counter() - t0
            total = combined_beta(res.beta, op.beta) if op.check is not None else res.beta
            state = update_alarm(
                self.alarms[model.name],
                self._alarm,
                judged=True,
                invalidated=total > 1.0,
                beta=total,
                weight=self._weight,
                unchecked=op.unchecked,
                # auto: a window the gate refused, judged with the term; or its operating
                # point checked with the term at DC: weaker evidence, it clears no ERROR
                hold=bool(term) or op_term,
            )
            self.alarms[model.name] = state
            general = res.method in (Method.SDP, Method.FAST)  # certified lower bound and a witness
            resp = self._responses[model.name]
            # over the bins β counts: noise outside the band cannot move the band's β
            noise_effect = input_noise_effect(
                resp.p22,
                resp.p23,
                datum.u_noise_std,
                datum.bin_weights,
                validation_band(datum, model),
            )
            warnings = res.warnings + measured_input_warning(noise_effect, res.beta)
            reports.append(
                WindowReport(
                    model=model.name,
                    start_ns=start_ns,
                    end_ns=end_ns,
                    n_periods=cfg.periods_per_window,
                    n_samples=n,
                    judged=True,
                    data_quality=with_warnings(judged_quality, warnings),
                    beta=res.beta,
                    beta_lower=res.beta if general else math.nan,
                    beta_upper=res.beta_upper if general else math.nan,
                    margin=res.margin,
                    invalidated=total > 1.0,
                    alarm=state.level,
                    convention=cfg.convention.value,
                    solver=res.method,
                    freqs_hz=res.freqs_hz,
                    w_min=res.w_min,
                    compute_time_s=elapsed,
                    warnings=warnings,
                    beta_op=op.beta,
                    beta_total=total,
                    raised_by=raised_by(res.beta, op.beta, total),
                    operating_point=f"{op.state}: {op.note}" if op.note else str(op.state),
                    op_state=op.state,
                    quality=judged_reason,
                    findings=res.findings,
                    input_leakage=res.input_leakage,
                    input_change=input_change,
                    input_noise=input_noise,
                    input_noise_effect=noise_effect,
                    beta_outside=math.nan if model.band is None else res.beta_outside,
                    lines_outside=res.lines_outside,
                    noise_beta=res.noise_beta,
                    noise_floor=res.noise_floor,
                    excited=excited_lines(
                        datum.u_bins, datum.n_periods, noise_std=datum.u_noise_std
                    ),
                )
            )
        return reports

    def _unjudged(
        self, name: str, start_ns: int, end_ns: int, reason: str, quality: WindowQuality
    ) -> WindowReport:
        state = update_alarm(
            self.alarms[name], self._alarm, judged=False, invalidated=False, beta=math.nan
        )
        self.alarms[name] = state
        return WindowReport(
            model=name,
            start_ns=start_ns,
            end_ns=end_ns,
            n_periods=self.config.periods_per_window,
            n_samples=self.config.window_samples,
            judged=False,
            data_quality=reason,
            beta=math.nan,
            beta_lower=math.nan,
            beta_upper=math.nan,
            margin=math.nan,
            invalidated=False,
            alarm=state.level,
            convention=self.config.convention.value,
            solver="",
            freqs_hz=np.zeros(0),
            w_min=np.zeros(0),
            compute_time_s=0.0,
            quality=quality,
            op_state=self.operating_points[name].state,
        )


def _not_periodic_text(moved: np.ndarray, change: np.ndarray, noise: np.ndarray) -> str:
    """Why the input gate refused a window, in words.

    A commanded input moved, or a measured one's period-to-period spread is more than noise
    (:data:`MEASURED_INPUT_RTOL`).
    """
    if moved.any():
        j = int(np.argmax(np.where(moved, change, -np.inf)))
        return (
            f"input not periodic: input {j} changes by {change[j]:.3g} from one period to the "
            "next (excitation started or changed; waiting for the plant to settle)"
        )
    j = int(np.argmax(noise))
    return (
        f"input not periodic: measured input {j} varies from period to period by "
        f"{noise[j]:.3g} of its RMS, more than noise may ({MEASURED_INPUT_RTOL:g}): the "
        "excitation changed (waiting for it to repeat)"
    )


def transient_gate_text(rho: float) -> str:
    """Why a window with the transient term on is not judged: the leakage left, ``rho``."""
    return (
        f"input not periodic: the model error the transient term picks up from the lines "
        f"around each bin may cost {rho:.3g} of the budget of w (>= 1, docs/theory.md): "
        "the window cannot test the model"
    )


def measured_input_warning(effect: float, beta: float) -> tuple[str, ...]:
    """The warning for a measured input's noise that may decide the verdict, if it may.

    ``effect`` (:func:`~twotank_validation.core.measured.input_noise_effect`) at least β's
    distance from 1: one sentence with what to do; otherwise nothing.
    """
    if not effect >= abs(1.0 - beta):
        return ()
    return (
        f"the measured inputs' noise may move beta by {effect:.3g}, as far as its distance "
        "from 1: the verdict is not settled; record more periods (the noise left falls as "
        "1/sqrt(periods)) or a quieter input sensor",
    )


def with_warnings(quality: str, warnings: Sequence[str]) -> str:
    """A judged window's ``data_quality``: ``quality`` and ``"; warning: <text>"`` per warning.

    ``quality`` itself when there is no warning (a clean window's text is ``"ok"``).
    """
    return "".join([quality, *(f"; warning: {w}" for w in warnings)])


def monitor_record(
    stamps_ns: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    config: MonitorConfig,
    models: Sequence[LFTModel],
    *,
    measured_inputs: Collection[str] = (),
) -> list[WindowReport]:
    """Offline: feed an already aligned record through the same monitor as the live node.

    Args:
        stamps_ns: (n,) int, sample stamps (ns), on the grid.
        u: (n, n_inputs) float.
        y: (n, n_outputs) float.
        config: monitor settings.
        models: models.
        measured_inputs: names of the inputs logged by a sensor (:class:`WindowMonitor`).
    """
    mon = WindowMonitor(config, models, measured_inputs=measured_inputs)
    t0 = int(stamps_ns[0])
    ts_ns = round(config.ts_s * NS_PER_S)
    out: list[WindowReport] = []
    for k in range(len(stamps_ns)):
        idx = (int(stamps_ns[k]) - t0 + ts_ns // 2) // ts_ns
        plausible = np.all(np.abs(u[k]) <= 1e6) and np.all(np.abs(y[k]) <= 1e6)  # NaN: False
        flag = None if plausible else "non-finite or implausible value"
        out.extend(
            mon.push(
                Sample(
                    idx, int(stamps_ns[k]), np.asarray(u[k], float), np.asarray(y[k], float), flag
                )
            )
        )
    return out
