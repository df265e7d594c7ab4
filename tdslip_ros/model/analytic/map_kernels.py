"""The equations of the approximate apex return map as compiled kernels of one lane, and its lane loop.

The closed forms, corrections and energy balance that :mod:`tdslip_ros.model.analytic.apex_map` derives (its
module docstring) are written here once, as scalar kernels of one lane (``lane_*``, compiled by
:mod:`tdslip_ros.model.compiled`), float or complex: the policies' solvers (:mod:`.controller_kernels`) call
them for one apex, :func:`stride_lanes` runs the whole map over the lanes of a batch, and a batch with any
complex input runs their complex128 specialisation (the complex step of :mod:`.closed_loop`; imaginary parts
are infinitesimal perturbations). Iterations (the corrections, the force root) stop per lane, so a lane's
result does not depend on the other lanes of its batch.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numba.extending import register_jitable

from tdslip_ros.model.arrays import Array
from tdslip_ros.model.compiled import atan2, inlined_kernel, is_complex, kernel, real
from tdslip_ros.model.dynamics import apex_energy
from tdslip_ros.model.events import NO_FAILURE_CODE, FailureKind, failure_code

CORRECTION_TOLERANCE = 1e-12
"""Relative change of p_hat below which further correction iterations stop."""
FORCE_ROOT_TOLERANCE = 1e-14
"""Relative step in t below which the safeguarded Newton search for the force root stops."""
FORCE_ROOT_ITERATIONS = 100
"""Bound on the steps of the force-root search (bisection alone needs about 50)."""

# The apex energy's one source (dynamics), compiled where a kernel calls it.
register_jitable(apex_energy)


# Failure codes per lane, shared with the exact plant (tdslip_ros.model.events): NO_FAILURE_CODE (-1) or the
# index of the FailureKind, so failure arrays of both maps compare directly (failure_from_code names them).
TOE_STUBBING = failure_code(FailureKind.TOE_STUBBING)  # apex below r0 cos(theta_td): the leg cannot be placed
NO_LIFTOFF = failure_code(FailureKind.NO_LIFTOFF)  # the approximate leg force never vanishes after the bottom
FALL = failure_code(FailureKind.FALL)  # liftoff with ydot <= 0: no next apex
REVERSAL = failure_code(FailureKind.REVERSAL)  # thetadot_td >= 0, or no forward speed at the next apex


class Angle(NamedTuple):
    """A constant phase held as its cosine and sine, so that cos(wd t + phase) needs no new trigonometry
    (scalars in a kernel, arrays in StanceApproximation)."""

    cos: Any
    sin: Any


@kernel
def angle_sum(a: Angle, b: Angle) -> Angle:
    return Angle(a.cos * b.cos - a.sin * b.sin, a.sin * b.cos + a.cos * b.sin)


@kernel
def angle_difference(a: Angle, b: Angle) -> Angle:
    return Angle(a.cos * b.cos + a.sin * b.sin, a.sin * b.cos - a.cos * b.sin)


@kernel
def angle_of(a: Angle) -> complex:
    return atan2(a.sin, a.cos)


class Wave(NamedTuple):
    """e^{-a t}, cos(wd t) and sin(wd t) at a time t: the only transcendental functions of t needed."""

    envelope: complex
    cos: complex
    sin: complex


@kernel
def wave_at(wave: Wave, phase: Angle) -> complex:
    """e^{-a t} cos(wd t + phase)."""
    value: complex = wave.envelope * (wave.cos * phase.cos - wave.sin * phase.sin)
    return value


class LaneApproximation(NamedTuple):
    """The closed-form stance of one lane (the fields of :class:`~.analytic.StanceApproximation`, parameters
    inline)."""

    m: float
    k: float
    r0: float
    c: float
    g: float
    theta_td: complex
    rdot_td: complex
    omega: complex
    omega_hat: complex
    zeta: complex
    omega_d: complex
    decay: float  # a = zeta omega_hat = c/(2m)
    equilibrium: complex  # F/omega_hat^2
    amplitude_a: complex  # A
    amplitude: complex  # M
    force_amplitude: complex  # Mbar
    x_rate: complex  # X
    y_amplitude: complex  # Y
    bottom_time: complex
    phase1: Angle
    phase2: Angle
    phase3: Angle


@kernel
def lane_approximation(
    m: float, k: float, r0: float, c: float, g: float, theta_td: complex, rdot_td: complex, omega: complex
) -> LaneApproximation:
    omega_hat = np.sqrt(k / m + 3.0 * omega**2)
    zeta = c / (2.0 * m * omega_hat)
    decay = c / (2.0 * m)
    damped_fraction = np.sqrt(1.0 - zeta**2)
    omega_d = omega_hat * damped_fraction
    amplitude_a = (g - r0 * omega**2) / omega_hat**2  # A = r0 - F/wh^2
    amplitude_b = (rdot_td + decay * amplitude_a) / omega_d
    amplitude = np.sqrt(amplitude_a**2 + amplitude_b**2)
    spring_term = k - c**2 / (2.0 * m)
    force_amplitude = np.sqrt(spring_term**2 + (c * omega_d) ** 2)
    phase1 = Angle(amplitude_a / amplitude, -amplitude_b / amplitude)
    phase2 = Angle(zeta, -damped_fraction)
    # Bottom: wd t_b + phi1 + phi2 = pi/2 (mod 2 pi), the first such t_b > 0.
    bottom_phase = np.pi / 2 - angle_of(angle_sum(phase1, phase2))
    bottom_phase = bottom_phase - 2.0 * np.pi * np.floor(real(bottom_phase) / (2.0 * np.pi))
    equilibrium = r0 - amplitude_a
    return LaneApproximation(
        m,
        k,
        r0,
        c,
        g,
        theta_td,
        rdot_td,
        omega,
        omega_hat,
        zeta,
        omega_d,
        decay,
        equilibrium,
        amplitude_a,
        amplitude,
        force_amplitude,
        omega * (3.0 - 2.0 * equilibrium / r0),
        2.0 * omega * amplitude / (r0 * omega_hat),
        bottom_phase / omega_d,
        phase1,
        phase2,
        Angle(spring_term / force_amplitude, c * omega_d / force_amplitude),
    )


@kernel
def lane_real_part(s: LaneApproximation) -> LaneApproximation:
    return LaneApproximation(
        s.m,
        s.k,
        s.r0,
        s.c,
        s.g,
        real(s.theta_td),
        real(s.rdot_td),
        real(s.omega),
        real(s.omega_hat),
        real(s.zeta),
        real(s.omega_d),
        s.decay,
        real(s.equilibrium),
        real(s.amplitude_a),
        real(s.amplitude),
        real(s.force_amplitude),
        real(s.x_rate),
        real(s.y_amplitude),
        real(s.bottom_time),
        Angle(real(s.phase1.cos), real(s.phase1.sin)),
        Angle(real(s.phase2.cos), real(s.phase2.sin)),
        Angle(real(s.phase3.cos), real(s.phase3.sin)),
    )


@kernel
def lane_wave(s: LaneApproximation, t: complex) -> Wave:
    angle = s.omega_d * t
    return Wave(np.exp(-s.decay * t), np.cos(angle), np.sin(angle))


class StanceState(NamedTuple):
    """Arrays in the API, scalars in a kernel."""

    r: Any
    rdot: Any
    theta: Any
    thetadot: Any


@kernel
def lane_state(s: LaneApproximation, wave: Wave, t: complex) -> StanceState:
    """r, rdot, theta, thetadot at t (eqs. 12-15), from the wave at t."""
    radial = wave_at(wave, s.phase1)
    lag = angle_difference(s.phase1, s.phase2)
    swing = wave_at(wave, lag) - lag.cos
    return StanceState(
        s.amplitude * radial + s.equilibrium,
        -s.omega_hat * s.amplitude * wave_at(wave, angle_sum(s.phase1, s.phase2)),
        s.theta_td + s.x_rate * t + s.y_amplitude * swing,
        s.x_rate - 2.0 * s.omega * s.amplitude * radial / s.r0,
    )


@kernel
def lane_leg_force(s: LaneApproximation, t: complex) -> complex:
    """Spring-damper force along the leg, k (r0 - r) - c rdot, in the closed form of (16)."""
    oscillation = wave_at(lane_wave(s, t), angle_sum(s.phase1, s.phase3))
    return s.k * s.amplitude_a - s.force_amplitude * s.amplitude * oscillation


@kernel
def lane_leg_force_rate(s: LaneApproximation, t: complex) -> complex:
    """Time derivative of :func:`lane_leg_force`."""
    oscillation = wave_at(lane_wave(s, t), angle_sum(angle_sum(s.phase1, s.phase3), s.phase2))
    return s.force_amplitude * s.omega_hat * s.amplitude * oscillation


@kernel
def lane_paper_liftoff(s: LaneApproximation) -> tuple[complex, bool]:
    q = s.k * s.amplitude_a / (s.force_amplitude * s.amplitude * np.exp(-2.0 * s.decay * s.bottom_time))
    after_bottom = (1.5 * np.pi + angle_of(angle_difference(s.phase2, s.phase3)) - np.arccos(q)) / s.omega_d
    exists = abs(real(q)) <= 1.0 and real(after_bottom) > 0.0
    return s.bottom_time + after_bottom, exists


@kernel
def lane_force_root_liftoff(s: LaneApproximation) -> tuple[complex, bool]:
    # The force decreases monotonically from the bottom to its minimum at phase 3 pi/2 - phi2.
    lower = real(s.bottom_time)
    upper = lower + real((np.pi - angle_of(s.phase3)) / s.omega_d)
    exists = real(lane_leg_force(s, upper)) <= 0.0
    start = real(lane_paper_liftoff(s)[0])
    t = start if np.isfinite(start) else 0.5 * (lower + upper)
    t = min(max(t, lower), upper)
    real_s = lane_real_part(s)
    for _ in range(FORCE_ROOT_ITERATIONS):
        force = real(lane_leg_force(real_s, t))
        rate = real(lane_leg_force_rate(real_s, t))
        if force > 0.0:
            lower = t
        else:
            upper = t
        newton = t - force / (rate if rate < 0.0 else -np.inf)
        t_new = newton if newton > lower and newton < upper else 0.5 * (lower + upper)
        done = abs(t_new - t) <= FORCE_ROOT_TOLERANCE * abs(t_new)
        t = t_new
        if done or not exists:
            break
    if is_complex(s.omega) or is_complex(s.rdot_td):
        # One complex Newton step from the real root carries the perturbation (implicit function theorem).
        return t - lane_leg_force(s, t) / lane_leg_force_rate(s, t), exists
    return t, exists


PAPER_LIFTOFF, FORCE_ROOT_LIFTOFF = 0, 1
"""The liftoff method's bit of a map variant (:func:`.analytic.map_variant_code`)."""
ENERGY_SPEED, LIFTOFF_SPEED = 0, 2
"""The next apex speed's bit of a map variant: from the energy balance, or the liftoff velocity of eq. 7."""


@kernel
def lane_liftoff(s: LaneApproximation, map_variant: int) -> tuple[complex, bool]:
    """Liftoff time and whether it exists (both methods: the docstring of :mod:`.apex_map`)."""
    if map_variant & FORCE_ROOT_LIFTOFF:
        return lane_force_root_liftoff(s)
    return lane_paper_liftoff(s)


@kernel
def lane_damping_loss(s: LaneApproximation, wave: Wave) -> complex:
    """E_c = int_0^t c rdot^2 (closed form of eq. 31, re-derived), from the wave at t."""
    double = Wave(wave.envelope**2, wave.cos**2 - wave.sin**2, 2.0 * wave.sin * wave.cos)
    phase = angle_sum(angle_sum(s.phase1, s.phase2), s.phase1)
    oscillation = phase.cos - wave_at(double, phase)
    scale = 0.5 * s.m * (s.amplitude * s.omega_hat) ** 2
    loss: complex = scale * (1.0 - double.envelope + s.zeta * oscillation)
    return loss


@kernel
def lane_hip_energy(
    s: LaneApproximation, tau0: complex, t_f: complex, t_end: complex, wave_end: Wave
) -> complex:
    """E_tau = int_0^T tau thetadot dt for the ramp tau0 (1 - t/t_f), T = min(t_f, t_end) (eq. 25);
    wave_end is the wave at t_end."""
    energy: complex = tau0 * lane_energy_per_torque(s, t_f, t_end, wave_end)
    return energy


@kernel
def lane_energy_per_torque(s: LaneApproximation, t_f: complex, t_end: complex, wave_end: Wave) -> complex:
    """E_tau/tau0 (:func:`lane_hip_energy`): the ramp-weighted mean angular rate, times the ramp's length."""
    if real(t_f) <= real(t_end):
        t = t_f
        wave = lane_wave(s, t_f)
    else:
        t = t_end
        wave = wave_end
    lag1 = angle_difference(s.phase1, s.phase2)
    lag2 = angle_difference(lag1, s.phase2)
    i0 = -(wave_at(wave, lag1) - lag1.cos) / s.omega_hat
    i1 = -t * wave_at(wave, lag1) / s.omega_hat - (wave_at(wave, lag2) - lag2.cos) / s.omega_hat**2
    mean_part = s.x_rate * (t - t**2 / (2.0 * t_f))
    oscillating_part = 2.0 * s.omega * s.amplitude / s.r0 * (i0 - i1 / t_f)
    rate: complex = mean_part - oscillating_part
    return rate


@kernel
def lane_torque_correction(tau0: complex, t_f: complex, t_lo: complex) -> complex:
    """dp_tau: time average over [0, t_lo] of the integrated ramp torque (eq. 21 for general t_f)."""
    shorter = t_lo if real(t_lo) <= real(t_f) else t_f
    longer = t_lo + t_f - shorter
    return tau0 * (shorter / 2.0 - shorter**2 / (6.0 * longer))


@kernel
def lane_gravity_correction(
    m: float, g: float, r0: float, theta_td: complex, t_lo: complex, r_lo: complex, theta_lo: complex
) -> complex:
    """dp_g of eq. 22: r sin(theta) interpolated linearly from touchdown to liftoff, then time-averaged."""
    correction: complex = m * g * t_lo / 6.0 * (2.0 * r0 * np.sin(theta_td) + r_lo * np.sin(theta_lo))
    return correction


class Touchdown(NamedTuple):
    """Arrays in the API, scalars in a kernel."""

    rdot: Any
    thetadot: Any
    failure: Any


@kernel
def lane_descent(r0: float, g: float, y: complex, xdot: complex, theta_td: complex) -> Touchdown:
    """P_d (eq. 6): apex (y, xdot) and touchdown angle to the polar touchdown velocities."""
    drop = y - r0 * np.cos(theta_td)
    ydot = -np.sqrt(2.0 * g * drop)
    sin, cos = np.sin(theta_td), np.cos(theta_td)
    rdot = -xdot * sin + ydot * cos
    thetadot = (-xdot * cos - ydot * sin) / r0
    failure = NO_FAILURE_CODE
    if real(drop) < 0.0:
        failure = TOE_STUBBING
    elif real(thetadot) >= 0.0:
        failure = REVERSAL
    return Touchdown(rdot, thetadot, failure)


@kernel
def converged(new: complex, old: complex, tolerance: float) -> bool:
    """new and old agree to ``tolerance`` relative, real and imaginary parts separately."""
    ok = abs(real(new) - real(old)) <= tolerance * abs(real(new))
    if is_complex(new) or is_complex(old):
        ok = ok and abs(new.imag - old.imag) <= tolerance * abs(new.imag)
    return ok


class StanceStart(NamedTuple):
    """The unforced stance of a touchdown: the start of the corrections, whatever the ramp (probes of the
    policies' solvers share it)."""

    momentum_td: complex
    approximation: LaneApproximation
    t_lo: complex
    liftoff_exists: bool
    wave: Wave  # at t_lo
    gravity_correction: complex  # dp_g of the first correction


@inlined_kernel
def lane_stance_start(
    m: float,
    k: float,
    r0: float,
    c: float,
    g: float,
    theta_td: complex,
    rdot_td: complex,
    thetadot_td: complex,
    map_variant: int,
) -> StanceStart:
    momentum_td = m * r0**2 * thetadot_td
    s = lane_approximation(m, k, r0, c, g, theta_td, rdot_td, momentum_td / (m * r0**2))
    t_lo, exists = lane_liftoff(s, map_variant)
    wave = lane_wave(s, t_lo)
    at_liftoff = lane_state(s, wave, t_lo)
    gravity = lane_gravity_correction(m, g, r0, theta_td, t_lo, at_liftoff.r, at_liftoff.theta)
    return StanceStart(momentum_td, s, t_lo, exists, wave, gravity)


class LaneStance(NamedTuple):
    """Outcome of the approximate stance map P_s with corrections, one lane (the fields of
    :class:`~.analytic.Stance`)."""

    momentum: complex
    t_lo: complex
    r_lo: complex
    theta_lo: complex
    rdot_lo: complex
    thetadot_lo: complex
    hip_energy: complex
    damping_loss: complex
    spring_energy: complex
    liftoff_exists: bool
    corrections_done: int
    approximation: LaneApproximation  # the last (most corrected) one
    energy_per_torque: complex  # e = E_tau/tau0: negative while the body swings forward over the ramp


LANE_STANCE_VALUES = 11
"""The fields of LaneStance that Stance holds as arrays (the others stay in the kernels)."""


@inlined_kernel
def lane_stance(
    start: StanceStart, tau0: complex, t_f: complex, corrections: int, map_variant: int
) -> LaneStance:
    """P_s (eqs. 17, 19-22) from the unforced stance: ``corrections`` updates of p_hat = p(0) + dp_tau + dp_g,
    fewer once p_hat changes by less than CORRECTION_TOLERANCE (relative)."""
    s = start.approximation
    m, k, r0, c, g = s.m, s.k, s.r0, s.c, s.g
    momentum = start.momentum_td
    t_lo, exists, gravity = start.t_lo, start.liftoff_exists, start.gravity_correction
    done = 0
    while done < corrections:
        if done > 0:
            at_liftoff = lane_state(s, lane_wave(s, t_lo), t_lo)
            gravity = lane_gravity_correction(m, g, r0, s.theta_td, t_lo, at_liftoff.r, at_liftoff.theta)
        corrected = start.momentum_td + lane_torque_correction(tau0, t_f, t_lo) + gravity
        stop = converged(corrected, momentum, CORRECTION_TOLERANCE) or not exists
        momentum = corrected
        done += 1
        s = lane_approximation(m, k, r0, c, g, s.theta_td, s.rdot_td, momentum / (m * r0**2))
        t_lo, exists = lane_liftoff(s, map_variant)
        if stop:
            break
    wave = start.wave if done == 0 else lane_wave(s, t_lo)
    at_liftoff = lane_state(s, wave, t_lo)
    energy_per_torque = lane_energy_per_torque(s, t_f, t_lo, wave)
    return LaneStance(
        momentum,
        t_lo,
        at_liftoff.r,
        at_liftoff.theta,
        at_liftoff.rdot,
        at_liftoff.thetadot,
        tau0 * energy_per_torque,
        lane_damping_loss(s, wave),
        0.5 * k * (at_liftoff.r - r0) ** 2,
        exists,
        done,
        s,
        energy_per_torque,
    )


class LaneStride(NamedTuple):
    """One stride of the approximate map, one lane (fields of :class:`~.analytic.Stride`)."""

    y: complex
    xdot: complex
    energy: complex
    failure: int
    touchdown: Touchdown
    stance: LaneStance


@inlined_kernel
def lane_stride(
    m: float,
    k: float,
    r0: float,
    c: float,
    g: float,
    y: complex,
    xdot: complex,
    angle: complex,
    tau0: complex,
    t_f: complex,
    corrections: int,
    map_variant: int,
) -> LaneStride:
    """The approximate apex return map P = P_a o P_s o P_d (eqs. 3-7) of one lane."""
    touchdown = lane_descent(r0, g, y, xdot, angle)
    start = lane_stance_start(m, k, r0, c, g, angle, touchdown.rdot, touchdown.thetadot, map_variant)
    stance = lane_stance(start, tau0, t_f, corrections, map_variant)
    return lane_ascent(m, g, y, xdot, touchdown, stance, map_variant)


@inlined_kernel
def lane_ascent(
    m: float, g: float, y: complex, xdot: complex, touchdown: Touchdown, stance: LaneStance, map_variant: int
) -> LaneStride:
    """The stride from the apex (y, xdot) through its touchdown and stance: the ascent P_a (eq. 7) to the next
    apex height, the next speed from the energy balance (ENERGY_SPEED) or the liftoff velocity of eq. 7
    (LIFTOFF_SPEED), and the stride's failure."""
    sin, cos = np.sin(stance.theta_lo), np.cos(stance.theta_lo)
    ydot_lo = stance.rdot_lo * cos - stance.r_lo * stance.thetadot_lo * sin
    xdot_lo = -stance.rdot_lo * sin - stance.r_lo * stance.thetadot_lo * cos
    y_next = stance.r_lo * cos + ydot_lo**2 / (2.0 * g)
    if map_variant & LIFTOFF_SPEED:
        xdot_next = xdot_lo
        energy_next = apex_energy(m, g, y_next, xdot_next)
        kinetic = 0.5 * xdot_next**2
    else:
        energy_next = (
            apex_energy(m, g, y, xdot) + stance.hip_energy - (stance.damping_loss + stance.spring_energy)
        )
        kinetic = energy_next / m - g * y_next
        xdot_next = np.sqrt(2.0 * kinetic)
    failure = touchdown.failure
    if failure == NO_FAILURE_CODE and not stance.liftoff_exists:
        failure = NO_LIFTOFF
    if failure == NO_FAILURE_CODE and not real(ydot_lo) > 0.0:
        failure = FALL
    if failure == NO_FAILURE_CODE and not (real(kinetic) > 0.0 and real(xdot_lo) > 0.0):
        failure = REVERSAL
    if failure != NO_FAILURE_CODE:
        y_next, xdot_next, energy_next = np.nan, np.nan, np.nan
    return LaneStride(y_next, xdot_next, energy_next, failure, touchdown, stance)


STRIDE_ROWS = 18
"""Rows of a block of strides (write_stride)."""


@kernel
def write_stride(out: Array, lane: int, stride: LaneStride) -> None:
    """One lane's stride into column ``lane`` of a block, in the order analytic.strides_of_block reads."""
    stance = stride.stance
    out[0, lane] = stride.y
    out[1, lane] = stride.xdot
    out[2, lane] = stride.energy
    out[3, lane] = stride.failure
    out[4, lane] = stride.touchdown.rdot
    out[5, lane] = stride.touchdown.thetadot
    out[6, lane] = stride.touchdown.failure
    out[7, lane] = stance.momentum
    out[8, lane] = stance.t_lo
    out[9, lane] = stance.r_lo
    out[10, lane] = stance.theta_lo
    out[11, lane] = stance.rdot_lo
    out[12, lane] = stance.thetadot_lo
    out[13, lane] = stance.hip_energy
    out[14, lane] = stance.damping_loss
    out[15, lane] = stance.spring_energy
    out[16, lane] = stance.liftoff_exists
    out[17, lane] = stance.corrections_done


@kernel
def stride_lanes(
    params: Array,
    y: Array,
    xdot: Array,
    angle: Array,
    tau0: Array,
    t_f: Array,
    corrections: int,
    map_variant: int,
    out: Array,
) -> None:
    """The map of every lane (arguments as :class:`~.arrays.Lanes` packs them) into the block ``out``."""
    for i in range(y.size):
        m, k, r0, c, g = params[0, i], params[1, i], params[2, i], params[3, i], params[4, i]
        stride = lane_stride(
            m, k, r0, c, g, y[i], xdot[i], angle[i], tau0[i], t_f[i], corrections, map_variant
        )
        write_stride(out, i, stride)
