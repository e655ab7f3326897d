"""Closed-loop windows: the controller known, the transient term written on the closed loop.

With a linear controller ``u = K_r r - K_y y + e`` (``e`` the excitation at its output, or
``K_r`` applied to an excitation added to the setpoints ``r``), every window's bins satisfy
``R(n) = U(n) + K_y(n) Y(n) = K_r(n) SP(n) + E(n) + T_K(n)`` exactly, ``T_K`` the
controller's transient (its state at the window's start less its state at the end, seen
through ``C (zI - A)^-1 z``). Written on the closed loop, a member of the model set gives
``Y = G_cl,Delta R + S_Delta T_p + V``: the per-bin closure of the LFT with ``K_y``
(:func:`close_loop`) is the same Problem 3 as the direct one for the same ``(U, Y)``.

The gain is in the transient term: ``T_K`` is fitted exactly (a few real numbers, the
controller's state change) from the lines the excitation does not drive, so the
reconstructed external input ``E_hat = R - T_K_hat`` is ~0 there and the model error the
transient estimate picks up from its lines, ``(G_cl,Delta - G_cl,0) E_hat(k_j)``, is ~0 —
where the direct formulation's ``U`` carries the loop's compensation at every line. The
window is then handed to the routes in the direct form, ``(U', Y')`` with
``Y' = Y - T_cl_hat`` and ``U' = E_hat - K_y Y'`` (per bin equivalent), so every route, the
fast path included, is unchanged. Docs: docs/theory.md §21.

Written by hand: python-control closes loops of systems, not of a frequency-response array
over an LFT's four blocks, and no maintained library fits a controller's transient.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Final

import numpy as np
import yaml

from twotank_validation.core import lti
from twotank_validation.core.band import masked_beta
from twotank_validation.core.datum import Datum
from twotank_validation.core.lti import StateSpace
from twotank_validation.core.model import (
    LFTModel,
    PlantResponse,
    parse_lti,
)
from twotank_validation.core.transient import (
    _ABSORBED,
    LocalPolynomial,
    TransientEstimate,
    _noise_needed,
    denominator,
    lowered,
    model_error_reach,
    scaled_noise,
    total_rho,
    validate_with_transient,
)
from twotank_validation.core.validate import BetaResult, validate_beta, validation_band
from twotank_validation.defaults import RIG_PI_FILTER_S, RIG_PI_KP, RIG_PI_TI_S
from twotank_validation.errors import ModelError, ModelFileError


@dataclass(frozen=True)
class PIPair:
    """Two discrete PI loops on a filtered measurement, mixed into two inputs.

    The law of :class:`twotank_validation.sim.control.PIController` in its linear region
    (no limit active, so the anti-windup term is zero): per loop ``i``, measurement filter
    ``yf_k = (1 - a) yf_k-1 + a y_k`` (``a = 1 - exp(-ts / filter_s)``, 1 without filter),
    ``v_k = kp e_k + I_k``, ``I_k+1 = I_k + ts kp / Ti e_k``, ``e = r - yf``; the loop outputs
    (total flow ``F``, hot fraction ``phi``) mixed into the valve commands
    ``hot = phi F``, ``cold = (1 - phi) F``, linearised at the window's mean commands.

    Attributes:
        ts_s: sample period (s).
        kp: (2,) gains [level, temperature].
        ti_s: (2,) integral times (s).
        filter_s: measurement filter time constant (s), 0: none.
        delay_samples: samples between a measurement and the command computed from it in
            the record (the rig's loop and its record: 1, each command is computed from the
            measurement of the sample before; the record pairs a command with the
            measurement taken after it was sent).
    """

    ts_s: float
    kp: tuple[float, float]
    ti_s: tuple[float, float]
    filter_s: float
    delay_samples: int = 1

    @property
    def shape(self) -> tuple[int, int]:
        """(outputs, inputs) of :meth:`system_at`: 2 valve commands, 2 setpoints + 2 outputs."""
        return (2, 4)

    def system_at(self, commands: np.ndarray) -> StateSpace:
        """The controller linearised at ``commands`` ((2,) mean [hot, cold]).

        Returns:
            Discrete, inputs ``[r_height, r_temperature, y_height, y_temperature]``,
            outputs ``[hot, cold]`` deviations; states ``[yf_h, I_F, yf_T, I_phi]``.

        Raises:
            ModelError: the mean total flow is not positive (no hot fraction).
        """
        hot, cold = (float(c) for c in np.asarray(commands, float).reshape(2))
        flow = hot + cold
        if not flow > 1e-9:
            raise ModelError(
                f"the window's mean valve commands ({hot:.3g}, {cold:.3g}) give no flow: the "
                "rig's PI cannot be linearised there"
            )
        frac = hot / flow
        a_f = 1.0 - math.exp(-self.ts_s / self.filter_s) if self.filter_s > 0.0 else 1.0
        a = np.zeros((4, 4))
        b = np.zeros((4, 4))
        c = np.zeros((2, 4))
        d = np.zeros((2, 4))
        for i in range(2):  # loop i: states 2i (filter memory), 2i+1 (integrator)
            kp, g = self.kp[i], self.ts_s * self.kp[i] / self.ti_s[i]
            s, q = 2 * i, 2 * i + 1
            a[s, s] = 1.0 - a_f
            a[q, s], a[q, q] = -g * (1.0 - a_f), 1.0
            b[s, 2 + i] = a_f
            b[q, i], b[q, 2 + i] = g, -g * a_f
            c[i, s], c[i, q] = -kp * (1.0 - a_f), 1.0
            d[i, i], d[i, 2 + i] = kp, -kp * a_f
        mix = np.array([[frac, flow], [1.0 - frac, -flow]])  # d[hot, cold] / d[F, phi]
        return delayed_measurement(
            StateSpace(a, b, mix @ c, mix @ d, dt_s=self.ts_s), self.delay_samples
        )


def delayed_measurement(system: StateSpace, samples: int) -> StateSpace:
    """``system`` (inputs ``[r; y]``) reading ``y`` ``samples`` samples late (shift states)."""
    ny = system.shape[1] // 2
    for _ in range(samples):
        n = system.n_states
        b_r, b_y = system.b[:, :ny], system.b[:, ny:]
        d_r, d_y = system.d[:, :ny], system.d[:, ny:]
        system = StateSpace(
            np.block([[system.a, b_y], [np.zeros((ny, n)), np.zeros((ny, ny))]]),
            np.block([[b_r, np.zeros((n, ny))], [np.zeros((ny, ny)), np.eye(ny)]]),
            np.hstack([system.c, d_y]),
            np.hstack([d_r, np.zeros_like(d_y)]),
            dt_s=system.dt_s,
        )
    return system


@dataclass(frozen=True)
class FixedController:
    """A linear controller given as one discrete system (inputs ``[r; y]``, outputs ``u``)."""

    system: StateSpace

    @property
    def shape(self) -> tuple[int, int]:
        """(outputs, inputs) of the system."""
        return self.system.shape

    def system_at(self, commands: np.ndarray) -> StateSpace:
        """The system, whatever the operating point."""
        del commands
        return self.system


Controller = PIPair | FixedController

RIG_CONTROLLER: Final = "rig"
"""The ``closed_loop_controller`` value naming the rig's PI pair at its default tuning."""


def controller_of(value: str, ts_s: float) -> Controller | None:
    """The controller a ``closed_loop_controller`` setting names.

    Args:
        value: ``""`` (none: the direct formulation), ``"rig"`` (the rig's PI pair,
            :data:`~twotank_validation.defaults.RIG_PI_KP` ...), or a YAML file holding
            ``pi_pair: {kp: [..], ti_s: [..], filter_s: .., delay_samples: ..}`` or
            ``lti: <an LTI of the model files' form, discrete, dt_s = ts_s>`` (inputs
            ``[setpoints; outputs]``, outputs the model's inputs, ``u = K [r; y] + e``).
        ts_s: the monitor's sample period (s).

    Raises:
        ModelFileError: a missing or malformed file, naming it and the forms.
    """
    if not value:
        return None
    if value == RIG_CONTROLLER:
        return PIPair(ts_s=ts_s, kp=RIG_PI_KP, ti_s=RIG_PI_TI_S, filter_s=RIG_PI_FILTER_S)
    path = Path(value)
    if not path.is_file():
        raise ModelFileError(
            f"closed_loop_controller {value!r}: no such file; give {RIG_CONTROLLER!r}, a "
            "controller YAML file, or nothing"
        )
    source = str(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise ModelFileError(f"{source}: not valid YAML: {err}") from err
    forms = "give pi_pair: {kp, ti_s, filter_s, delay_samples} or lti: {ss: ...} (discrete)"
    if not isinstance(doc, Mapping) or len(doc) != 1 or next(iter(doc)) not in ("pi_pair", "lti"):
        raise ModelFileError(f"{source}: not a controller: {forms}")
    ((kind, body),) = doc.items()
    if kind == "lti":
        system = parse_lti(body, source, "lti")
        if system.dt_s is None or not math.isclose(system.dt_s, ts_s):
            raise ModelFileError(
                f"{source}: the controller must be discrete at the monitor's {ts_s:g} s "
                f"(dt_s: {ts_s:g}), found dt_s {system.dt_s!r}"
            )
        return FixedController(system)
    if not isinstance(body, Mapping) or not {"kp", "ti_s"} <= set(body) <= {
        "kp",
        "ti_s",
        "filter_s",
        "delay_samples",
    }:
        raise ModelFileError(f"{source}: pi_pair takes kp, ti_s, filter_s, delay_samples: {forms}")
    try:
        kp = tuple(float(v) for v in body["kp"])
        ti = tuple(float(v) for v in body["ti_s"])
        filt = float(body.get("filter_s", 0.0))
        delay = int(body.get("delay_samples", 1))
    except (TypeError, ValueError) as err:
        raise ModelFileError(f"{source}: pi_pair: {err}: {forms}") from err
    good = len(kp) == len(ti) == 2 and all(v > 0 and math.isfinite(v) for v in (*kp, *ti))
    if not (good and filt >= 0.0 and math.isfinite(filt) and delay >= 0):
        raise ModelFileError(
            f"{source}: pi_pair needs two positive kp and ti_s, filter_s >= 0 and "
            "delay_samples >= 0"
        )
    return PIPair(ts_s=ts_s, kp=(kp[0], kp[1]), ti_s=(ti[0], ti[1]), filter_s=filt,
                  delay_samples=delay)  # fmt: skip


def feedback_response(system: StateSpace, theta: np.ndarray) -> np.ndarray:
    """(n_bins, nu, ny) complex, ``K_y`` at ``theta`` (``u = K_r r - K_y y``); 0 at DC.

    DC is left at 0: an integrating controller is infinite there, and the zero-frequency
    bin stays in the direct form (the operating-point check, docs/theory.md §8).
    """
    ny = system.shape[1] // 2
    out = np.zeros((theta.size, system.shape[0], ny), complex)
    out[1:] = -lti.frequency_response(system, theta[1:])[:, :, ny:]
    return out


def transient_basis(system: StateSpace, theta: np.ndarray, dft_scale: float) -> np.ndarray:
    """(n_bins, nu, nx) complex, ``c_N C (zI - A)^-1 z``: the controller's transient per state.

    Over ``N`` samples a discrete system gives ``Y(n) = G(n) U(n) + B(n) (x_0 - x_N)`` at
    every DFT line (``z^N = 1``); 0 at DC.
    """
    z = np.exp(1j * theta[1:])
    nx = system.n_states
    out = np.zeros((theta.size, system.shape[0], nx), complex)
    if nx:
        zi_a = z[:, None, None] * np.eye(nx)[None] - system.a[None]
        res = np.linalg.solve(zi_a, np.broadcast_to(np.eye(nx), (z.size, nx, nx)))
        out[1:] = dft_scale * np.einsum("pn,knm->kpm", system.c, res) * z[:, None, None]
    return out


def close_loop(resp: PlantResponse, k_y: np.ndarray) -> PlantResponse:
    """The LFT closed per bin with ``u = R - K_y y`` (a star product; Delta's blocks kept).

    ``S = (I + P23 K)^-1``; ``y = S (P21 v + P22 w + P23 R)``,
    ``z = (P1. - P13 K S P2.) [v; w; R]``.

    Args:
        resp: P at the bins.
        k_y: (n_bins, nu, ny) complex, the feedback (:func:`feedback_response`).
    """
    nz = resp.blocks.nz
    top, bottom = resp.p[:, :nz], resp.p[:, nz:]
    eye = np.eye(resp.ny)[None]
    s = np.linalg.inv(eye + resp.p23 @ k_y)
    new_bottom = s @ bottom
    new_top = top - resp.p13 @ k_y @ new_bottom
    return replace(resp, p=np.concatenate([new_top, new_bottom], axis=1))


@dataclass(frozen=True)
class ExternalInput:
    """The external signal of a closed-loop window, reconstructed per bin.

    Attributes:
        e_hat: (n_bins, nu) complex, ``U + K_y Y - B dx`` (DC: ``U(0)``).
        state_change: (nx,) float, ``dx``, the controller's fitted ``x_0 - x_N``.
        non_periodic: ``||E_hat||`` at the fitted lines over ``||E_hat||`` at the driven ones
            (bins 1..N/2): ~0 for a linear controller and periodic excitation; large when a
            limit or the anti-windup acted, a setpoint changed, or ``K`` is not the loop's.
    """

    e_hat: np.ndarray
    state_change: np.ndarray
    non_periodic: float


def external_input(
    u_bins: np.ndarray,
    y_bins: np.ndarray,
    k_y: np.ndarray,
    basis: np.ndarray,
    fit: np.ndarray,
) -> ExternalInput:
    """Reconstruct ``E`` from ``U``, ``Y`` and the controller (least squares over ``fit``).

    Args:
        u_bins: (n_bins, nu) complex, scaled DFT of the inputs.
        y_bins: (n_bins, ny) complex.
        k_y: (n_bins, nu, ny) complex (:func:`feedback_response`).
        basis: (n_bins, nu, nx) complex (:func:`transient_basis`).
        fit: (n_bins,) bool, the lines the excitation does not drive (DC excluded).
    """
    r = u_bins + (k_y @ y_bins[:, :, None])[:, :, 0]
    dx = fit_state_change(basis, fit) @ _stacked(r[fit])
    e_hat = r - basis @ dx
    e_hat[0] = u_bins[0]
    driven = ~fit
    driven[0] = False
    on = float(np.linalg.norm(e_hat[driven]))
    off = float(np.linalg.norm(e_hat[fit]))
    return ExternalInput(e_hat, dx, off / on if on > 0.0 else math.inf)


def fit_state_change(basis: np.ndarray, fit: np.ndarray) -> np.ndarray:
    """(nx, 2 n_fit nu) float, the least-squares map from ``R`` at the fitted lines to ``dx``.

    ``dx`` is real: the real and imaginary parts are stacked (:func:`_stacked`).
    """
    nx = basis.shape[2]
    if not (nx and fit.any()):
        return np.zeros((nx, 2 * int(fit.sum()) * basis.shape[1]))
    a = basis[fit].reshape(-1, nx)
    return np.asarray(np.linalg.pinv(np.vstack([a.real, a.imag])))


def _stacked(x: np.ndarray) -> np.ndarray:
    flat = x.reshape(-1)
    return np.concatenate([flat.real, flat.imag])


def closed_loop_poles(plant: StateSpace, system: StateSpace) -> np.ndarray:
    """(n,) complex, the poles of ``plant`` under the feedback ``u = -K_y y``.

    ``plant`` discrete at the controller's sample period; output delays are not states
    here (a delayed plant's closed loop is approximated by the undelayed one's: only the
    transient estimate's weighting uses these poles).
    """
    ny = system.shape[1] // 2
    bk, dk = -system.b[:, ny:], -system.d[:, ny:]  # K_y's (u = -K_y y): B, D
    ck = system.c
    # y = Cp x + Dp u, u = -(Ck xk + Dk y)  ->  y = L (Cp x - Dp Ck xk), L = (I + Dp Dk)^-1
    lmat = np.linalg.inv(np.eye(plant.shape[0]) + plant.d @ dk)
    y_x, y_k = lmat @ plant.c, -lmat @ plant.d @ ck
    u_x, u_k = -dk @ y_x, -ck - dk @ y_k
    a = np.block(
        [
            [plant.a + plant.b @ u_x, plant.b @ u_k],
            [bk @ y_x, system.a + bk @ y_k],
        ]
    )
    return np.asarray(np.linalg.eigvals(a), complex)


def closed_loop_estimate(
    lpm: LocalPolynomial, model: LFTModel, system: StateSpace, ts_s: float, n_samples: int
) -> TransientEstimate:
    """The transient estimate over the nominal closed loop's and the weights' poles."""
    weights = [p.weight for p in model.perturbations] + [c.weight for c in model.noise]
    poles = [closed_loop_poles(model.nominal_discrete(ts_s), system)]
    poles += [np.linalg.eigvals(lti.discretise(w, ts_s, model.intersample).a) for w in weights]
    return TransientEstimate.of(lpm, denominator(np.concatenate(poles), n_samples))


def error_gain(resp: PlantResponse, k_y: np.ndarray) -> np.ndarray:
    """(n_bins,) float, a bound of ``||I + G_Delta K_y||`` over ``||Delta|| <= 1``.

    ``||I + P23 K|| + ||P21|| ||P13 K|| / (1 - ||P11||)`` (inf where ``||P11|| >= 1``): an
    error ``e`` in ``Y'`` moves ``U' = E_hat - K_y Y'`` too, and a member needs
    ``(I + G_Delta K_y) e`` more of its noise.
    """
    eye = np.eye(resp.ny)[None]
    nominal = np.linalg.norm(eye + resp.p23 @ k_y, ord=2, axis=(1, 2))
    if resp.blocks.nv == 0:
        return np.asarray(nominal)
    gain = np.linalg.norm(resp.p11, ord=2, axis=(1, 2))
    spread = np.linalg.norm(resp.p21, ord=2, axis=(1, 2)) * np.linalg.norm(
        resp.p13 @ k_y, ord=2, axis=(1, 2)
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        extra = np.where(gain < 1.0, spread / (1.0 - gain), np.where(spread > 0, np.inf, 0.0))
    return np.asarray(nominal + extra)


@dataclass(frozen=True)
class LoopAtBins:
    """What a controller and a model give at a window's bins, once per operating point.

    Attributes:
        system: the controller (inputs ``[r; y]``, outputs ``u``).
        k_y: (n_bins, nu, ny) complex (:func:`feedback_response`).
        basis: (n_bins, nu, nx) complex (:func:`transient_basis`).
        fit: (n_bins,) bool, the lines between the harmonics (DC excluded).
        fit_map: :func:`fit_state_change` of ``basis`` over ``fit``.
        closed: P closed per bin (:func:`close_loop`).
        estimate: the transient estimate over the nominal closed loop's poles.
        scaled: P with its noise columns scaled by the estimate's noise scale.
        gain: (n_bins,) float, :func:`error_gain`.
    """

    system: StateSpace
    k_y: np.ndarray
    basis: np.ndarray
    fit: np.ndarray
    fit_map: np.ndarray
    closed: PlantResponse
    estimate: TransientEstimate
    scaled: PlantResponse
    gain: np.ndarray

    @classmethod
    def of(
        cls,
        system: StateSpace,
        model: LFTModel,
        resp: PlantResponse,
        lpm: LocalPolynomial,
        datum: Datum,
    ) -> LoopAtBins:
        """Prepare ``system`` with ``model`` (P ``resp``) for windows shaped like ``datum``.

        Raises:
            ModelError: one period per window (no line is free of the excitation), or the
                controller's channels are not the model's.
        """
        if datum.n_periods < 2:
            raise ModelError(
                "the closed-loop formulation needs two or more periods per window (the "
                "controller's transient is fitted between the harmonics): set "
                "window_periods >= 2"
            )
        if system.shape != (resp.nu, 2 * resp.ny):
            raise ModelError(
                f"the controller has {system.shape[1]} inputs and {system.shape[0]} outputs; "
                f"model {model.name!r} needs {2 * resp.ny} ([setpoints; outputs]) and "
                f"{resp.nu} (its inputs)"
            )
        k_y = feedback_response(system, datum.theta)
        basis = transient_basis(system, datum.theta, datum.convention.dft_scale(datum.n_samples))
        fit = ~datum.harmonic_bins
        est = closed_loop_estimate(lpm, model, system, datum.ts_s, datum.n_samples)
        return cls(
            system=system,
            k_y=k_y,
            basis=basis,
            fit=fit,
            fit_map=fit_state_change(basis, fit),
            closed=close_loop(resp, k_y),
            estimate=est,
            scaled=scaled_noise(resp, est.noise_scale),
            gain=error_gain(resp, k_y),
        )


@dataclass(frozen=True)
class ClosedLoopRemoved:
    """A closed-loop window in the direct form, with its transient term removed.

    Attributes:
        datum: ``(U', Y')``: ``Y' = Y - T_cl_hat``, ``U' = E_hat - K_y Y'`` (DC untouched),
            the periodicity findings the transient term accounts for cleared.
        response: P with its noise columns scaled by the estimate's ``sqrt(1 + leverage)``.
        external: the reconstructed external input.
        transient: (n_bins, ny) complex, ``T_cl_hat``.
        rho: (n_bins,) float, the least ``||W(n)||`` the picked-up model error may need
            (``||P22s^+|| error_gain ||eps||``, ``eps`` from the closed loop's reach).
    """

    datum: Datum
    response: PlantResponse
    external: ExternalInput
    transient: np.ndarray
    rho: np.ndarray


def remove_closed_loop_transient(datum: Datum, loop: LoopAtBins) -> ClosedLoopRemoved:
    """Reconstruct ``E``, estimate the closed loop's transient and return the direct form.

    Args:
        datum: the window.
        loop: :meth:`LoopAtBins.of` the controller at the window's operating point.
    """
    r = datum.u_bins + (loop.k_y @ datum.y_bins[:, :, None])[:, :, 0]
    dx = loop.fit_map @ _stacked(r[loop.fit])
    e_hat = r - loop.basis @ dx
    e_hat[0] = datum.u_bins[0]
    driven = ~loop.fit
    driven[0] = False
    on, off = np.linalg.norm(e_hat[driven]), np.linalg.norm(e_hat[loop.fit])
    ext = ExternalInput(e_hat, dx, float(off / on) if on > 0.0 else math.inf)
    residual = datum.y_bins - (loop.closed.p23 @ e_hat[:, :, None])[:, :, 0]
    t_hat = loop.estimate.apply(residual)
    eps = loop.estimate.bound(model_error_reach(loop.closed, e_hat))
    with np.errstate(invalid="ignore"):
        rho = _noise_needed(loop.scaled, eps * loop.gain[:, None])
    y_new = datum.y_bins - t_hat
    u_new = e_hat - (loop.k_y @ y_new[:, :, None])[:, :, 0]
    u_new[0] = datum.u_bins[0]
    per = datum.periodicity
    cleared = replace(
        per,
        findings=tuple(f for f in per.findings if f not in _ABSORBED),
        input_periodic=True,
        transient_suspected=False,
        last_change=np.zeros_like(per.last_change),
    )
    return ClosedLoopRemoved(
        datum=replace(datum, u_bins=u_new, y_bins=y_new, periodicity=cleared),
        response=loop.scaled,
        external=ext,
        transient=t_hat,
        rho=np.where(np.isnan(rho), np.inf, rho),
    )


def validate_closed_loop(
    datum: Datum, model: LFTModel, loop: LoopAtBins, *, method: str = "auto"
) -> tuple[BetaResult, float]:
    """β of a closed-loop window on the closed-loop formulation, on any route.

    As :func:`twotank_validation.core.transient.validate_with_transient`: the routes solve the
    direct form of the transformed window; each bin's minimum is lowered by ``rho``.

    Returns:
        The result (``input_leakage`` the total ``rho``) and that total.
    """
    removed = remove_closed_loop_transient(datum, loop)
    res = validate_beta(removed.datum, model, method=method, response=removed.response)
    mask = validation_band(datum, model)
    low = lowered(res.w_min, removed.rho)
    rho = total_rho(removed.rho, datum.bin_weights, mask)
    beta = masked_beta(low, datum.bin_weights, mask)
    return replace(
        res, w_min=low, beta=beta, beta_upper=max(res.beta_upper, beta), input_leakage=rho
    ), rho


OPERATING_POINT_DECIMALS: Final = 2
"""The window's mean commands are rounded to this many decimals to pick the controller's
linearisation (a cache key): any ``K_y`` keeps the closed-loop problem equal to the direct
one, a nearby one only leaves a little more of ``E_hat`` at the fitted lines (``rho``)."""


@dataclass(frozen=True)
class ClosedLoopJudge:
    """The window path's judge with the controller known.

    Called as :func:`~twotank_validation.core.transient.validate_with_transient`.

    The closed-loop formulation first; where its leakage reaches the gate (``rho >= 1``: a
    limit, the anti-windup or a setpoint change left ``E_hat`` far from periodic, or ``K``
    is not the loop's), the direct formulation of the same window (docs/theory.md §21).

    Attributes:
        controller: the loop's controller.
        lpm: the window's local polynomial.
    """

    controller: Controller
    lpm: LocalPolynomial
    _loops: dict[tuple[str, tuple[float, ...]], LoopAtBins] = field(
        default_factory=dict, compare=False, repr=False
    )

    def loop(self, datum: Datum, model: LFTModel, resp: PlantResponse) -> LoopAtBins:
        """The prepared loop at ``datum``'s operating point (kept for the next windows)."""
        point = np.round(datum.u_bias, OPERATING_POINT_DECIMALS)
        key = (model.name, tuple(float(c) for c in point))
        if key not in self._loops:
            if len(self._loops) > 32:  # a slow drift of the operating point: start again
                self._loops.clear()
            system = self.controller.system_at(point)
            self._loops[key] = LoopAtBins.of(system, model, resp, self.lpm, datum)
        return self._loops[key]

    def __call__(
        self,
        datum: Datum,
        model: LFTModel,
        est: TransientEstimate,
        *,
        method: str = "auto",
        response: PlantResponse | None = None,
        scaled: PlantResponse | None = None,
    ) -> tuple[BetaResult, float]:
        """(result, rho) of the closed-loop formulation, or of ``est``'s direct one."""
        resp = response if response is not None else model.response(datum.theta, datum.ts_s)
        try:
            loop = self.loop(datum, model, resp)
        except ModelError:  # no linearisation here (the valves shut): the direct form
            loop = None
        if loop is not None:
            res, rho = validate_closed_loop(datum, model, loop, method=method)
            if rho < 1.0:
                return res, rho
        return validate_with_transient(
            datum, model, est, method=method, response=resp, scaled=scaled
        )


def closed_loop_judge(
    controller: Controller | None,
    lpm: LocalPolynomial | None,
    models: Sequence[LFTModel] = (),
    n_periods: int = 2,
) -> ClosedLoopJudge | None:
    """The judge for a monitor (None without a controller), its settings checked up front.

    Raises:
        ModelError: a controller without the transient term (the formulation is the
            transient term's, written on the closed loop), one period per window, or a
            model whose inputs and outputs are not the controller's.
    """
    if controller is None:
        return None
    if lpm is None:
        raise ModelError(
            "a closed-loop controller needs the transient term: set transient to "
            "local_polynomial or auto"
        )
    if n_periods < 2:
        raise ModelError(
            "the closed-loop formulation needs two or more periods per window (the "
            "controller's transient is fitted between the harmonics): set periods_per_window "
            ">= 2"
        )
    nu, n_in = controller.shape
    for m in models:
        if (m.nu, 2 * m.ny) != (nu, n_in):
            raise ModelError(
                f"the controller has {n_in} inputs ([setpoints; outputs]) and {nu} outputs; "
                f"model {m.name!r} has {m.ny} outputs and {m.nu} inputs: give a controller "
                "of its channels"
            )
    return ClosedLoopJudge(controller, lpm)
