"""The rigid body's exact map against a reference stride integrated here, in Cartesian coordinates.

Derived here from scratch, sharing nothing with the model but the API under test: the body's centre of mass
(X, Y) and pitch phi obey m (X, Y)'' = F - m g yhat and J phi'' = (R(phi) d) x F - tau, where d is the hip's
offset from the centre of mass in the body frame and F = f e_r + (tau / r) e_theta is the force the massless
leg puts on the body at the hip (its ground force: the leg carries no momentum, and its moment balance about
the hip gives F's tangential part), with f = k (r0 - r) - c rdot, e_r = (-sin theta, cos theta) and
e_theta = (-cos theta, -sin theta). The leg's (r, theta, rdot, thetadot) are read off the hip's position
and velocity relative to the toe. Then dE/dt = F . v_hip - tau phidot + k (r - r0) rdot
= tau (thetadot - phidot) - c rdot^2 for E = m |v|^2 / 2 + J phidot^2 / 2 + m g Y + k (r - r0)^2 / 2,
which the reference checks on its own integration. Flight is ballistic with a constant spin; touchdown is
the first root of hip_y(t) = r0 cos(theta_td) after the apex, bracketed on a grid and refined by brentq.

The model integrates the stance in the leg's polar coordinates; this file integrates the centre of mass's
Cartesian coordinates with its own DOP853 solve (rtol = atol = 1e-12), its own touchdown root, its own
liftoff event (f falls through 0), and its own energy integrals, so that agreement to 1e-9 is a check of
the model's equations and of its event handling, not of a shared formula.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from tdslip_ros.model.params import ApexState, HopperParams, RigidBody, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map

M, R0, G = 80.0, 1.0, 9.81
K = 36.0 * M * G / R0  # the paper's kbar = k r0 / (m g) = 36
C = 2.0 * 0.08 * math.sqrt(M * K)  # zeta0 = c / (2 sqrt(m k)) = 0.08
TOL = 1e-12  # the reference's DOP853 tolerances
AGREE = 1e-9  # model against reference: absolute (SI), and relative for the energies

# (body, COM apex, command), each a clean stride. The apexes put the hip's apex near 1.1 m, so a hip below
# the centre of mass starts with its centre of mass higher. A hip below the centre of mass pitches the body
# forward (clockwise) under the backward ground force of a decelerating stance, so those bodies run at
# 4 m/s and 18 deg, where the stance's horizontal impulse nearly cancels, and do not tip (60 deg).
CASES = {
    "upright trunk, hip below": (
        RigidBody(inertia=M * 0.3**2, hip_x=0.0, hip_y=-0.3, tip_limit=math.radians(60)),
        ApexState(y=1.4, xdot=4.0, pitch=0.02, pitch_rate=-0.1),
        StanceCommand(touchdown_angle=math.radians(18), tau0=-80.0, t_f=0.2),
    ),
    "hip behind and below": (
        RigidBody(inertia=10.0, hip_x=-0.1, hip_y=-0.2, tip_limit=math.radians(60)),
        ApexState(y=1.3, xdot=4.0, pitch=-0.03, pitch_rate=0.8),
        StanceCommand(touchdown_angle=math.radians(18), tau0=-80.0, t_f=0.15),
    ),
    "hip at the centre of mass": (
        RigidBody(inertia=5.0, hip_x=0.0, hip_y=0.0, tip_limit=math.radians(60)),
        ApexState(y=1.1, xdot=3.5, pitch=0.05, pitch_rate=0.2),
        StanceCommand(touchdown_angle=math.radians(22), tau0=-50.0, t_f=0.1),
    ),
}


def _rotate(d: tuple[float, float], phi: float) -> tuple[float, float]:
    """R(phi) d, R the counter-clockwise rotation."""
    return d[0] * math.cos(phi) - d[1] * math.sin(phi), d[0] * math.sin(phi) + d[1] * math.cos(phi)


def _leg(z: np.ndarray, toe_x: float, d: tuple[float, float]) -> tuple:
    """(r, theta, rdot, thetadot, e_r, e_theta, R(phi) d) of the stance state z = (X, Y, phi, Xd, Yd, phid,
    hip work, damper loss), read off the hip's position and velocity relative to the toe."""
    ox, oy = _rotate(d, z[2])
    rel_x, rel_y = z[0] + ox - toe_x, z[1] + oy  # hip - toe
    v_x, v_y = z[3] - z[5] * oy, z[4] + z[5] * ox  # hip velocity: v_com + phid zhat x R(phi) d
    r = math.hypot(rel_x, rel_y)
    e_r = (rel_x / r, rel_y / r)
    e_theta = (-e_r[1], e_r[0])
    rdot = e_r[0] * v_x + e_r[1] * v_y
    thetadot = (e_theta[0] * v_x + e_theta[1] * v_y) / r
    return r, math.atan2(-rel_x, rel_y), rdot, thetadot, e_r, e_theta, (ox, oy)


def _energy(z: np.ndarray, toe_x: float, d: tuple[float, float], inertia: float) -> float:
    r = _leg(z, toe_x, d)[0]
    kinetic = 0.5 * M * (z[3] ** 2 + z[4] ** 2) + 0.5 * inertia * z[5] ** 2
    return kinetic + M * G * z[1] + 0.5 * K * (r - R0) ** 2


def reference_stride(
    inertia: float,
    d: tuple[float, float],
    apex: tuple[float, float, float, float],
    theta_td: float,
    tau0: float,
    t_f: float,
) -> dict[str, float]:
    """One stride from the apex (y, xdot, pitch, pitch_rate) at x = 0, t = 0; plain floats so that a mirrored
    call (negative xdot, theta_td, hip_x) works too."""
    y_a, xdot, phi0, spin = apex

    def clearance(t: float) -> float:  # hip height above the toe's touchdown height
        return y_a - 0.5 * G * t * t + _rotate(d, phi0 + spin * t)[1] - R0 * math.cos(theta_td)

    assert clearance(0.0) > 0.0, "the toe starts below the ground"
    t, step = 0.0, 1e-3
    while clearance(t + step) > 0.0:
        t += step
        assert t < 5.0
    t_td = brentq(clearance, t, t + step, xtol=1e-15, rtol=1e-15)
    phi_td = phi0 + spin * t_td
    z0 = np.array([xdot * t_td, y_a - 0.5 * G * t_td**2, phi_td, xdot, -G * t_td, spin, 0.0, 0.0])
    toe_x = z0[0] + _rotate(d, phi_td)[0] + R0 * math.sin(theta_td)

    def field(tau_of_s):
        def rhs(s: float, z: np.ndarray) -> np.ndarray:
            tau = tau_of_s(s)
            r, _, rdot, thetadot, e_r, e_t, (ox, oy) = _leg(z, toe_x, d)
            f = K * (R0 - r) - C * rdot
            fx, fy = f * e_r[0] + tau / r * e_t[0], f * e_r[1] + tau / r * e_t[1]
            phidd = (ox * fy - oy * fx - tau) / inertia
            return np.array(
                [z[3], z[4], z[5], fx / M, fy / M - G, phidd, tau * (thetadot - z[5]), C * rdot**2]
            )

        return rhs

    def leg_force(s: float, z: np.ndarray) -> float:
        r, _, rdot, *_ = _leg(z, toe_x, d)
        return K * (R0 - r) - C * rdot

    leg_force.terminal, leg_force.direction = True, -1.0
    assert leg_force(0.0, z0) > 0.0
    z, s_lo = z0, None
    for span, tau_of_s in (((0.0, t_f), lambda s: tau0 * (1.0 - s / t_f)), ((t_f, 3.0), lambda s: 0.0)):
        sol = solve_ivp(field(tau_of_s), span, z, method="DOP853", rtol=TOL, atol=TOL, events=leg_force)
        assert sol.status >= 0, sol.message
        if sol.t_events[0].size:
            s_lo, z = float(sol.t_events[0][0]), sol.y_events[0][0]
            break
        z = sol.y[:, -1]
    assert s_lo is not None, "no liftoff"
    r, theta, rdot, thetadot, *_ = _leg(z, toe_x, d)
    t_rise = z[4] / G
    assert t_rise > 0.0
    return {
        "t_td": t_td,
        "t_lo": t_td + s_lo,
        "toe_x": toe_x,
        "td_x": z0[0],
        "td_y": z0[1],
        "td_ydot": z0[4],
        "td_pitch": phi_td,
        "x": z[0],
        "y": z[1],
        "xdot": z[3],
        "ydot": z[4],
        "pitch": z[2],
        "pitch_rate": z[5],
        "r": r,
        "theta": theta,
        "rdot": rdot,
        "thetadot": thetadot,
        "apex_y": z[1] + 0.5 * z[4] ** 2 / G,
        "apex_pitch": z[2] + z[5] * t_rise,
        "apex_time": t_td + s_lo + t_rise,
        "hip_work": z[6],
        "damping_loss": z[7],
        "spring_loss": 0.5 * K * (r - R0) ** 2,
        "energy_td": _energy(z0, toe_x, d, inertia),
        "energy_lo": _energy(z, toe_x, d, inertia),
    }


def _reference(body: RigidBody, apex: ApexState, command: StanceCommand) -> dict[str, float]:
    return reference_stride(
        body.inertia,
        (body.hip_x, body.hip_y),
        (apex.y, apex.xdot, apex.pitch, apex.pitch_rate),
        command.touchdown_angle,
        command.tau0,
        command.t_f,
    )


def _params(body: RigidBody | None) -> HopperParams:
    return HopperParams(m=M, k=K, r0=R0, c=C, g=G, body=body)


@pytest.fixture(scope="module", params=list(CASES), ids=list(CASES))
def case(request):
    body, apex, command = CASES[request.param]
    res = apex_return_map(_params(body), apex, command)
    assert res.failure is None, res.reason
    return body, apex, command, res, _reference(body, apex, command)


def _differences(pairs: dict[str, tuple[float, float]]) -> dict[str, float]:
    differences = {name: abs(model - reference) for name, (model, reference) in pairs.items()}
    print("max |model - reference|:", max(differences.values()), differences)
    return differences


def test_next_apex_event_times_and_event_states_agree_with_the_reference(case):
    _, _, _, res, ref = case
    td, lo, apex = res.touchdown, res.liftoff, res.apex
    pairs = {
        "t_td": (td.t, ref["t_td"]),
        "td x": (td.x, ref["td_x"]),
        "td y": (td.y, ref["td_y"]),
        "td ydot": (td.ydot, ref["td_ydot"]),
        "td pitch": (td.pitch, ref["td_pitch"]),
        "toe_x": (lo.toe_x, ref["toe_x"]),
        "t_lo": (lo.t, ref["t_lo"]),
        **{f"lo {name}": (getattr(lo, name), ref[name]) for name in (
            "x", "y", "xdot", "ydot", "r", "theta", "rdot", "thetadot", "pitch", "pitch_rate")},
        "apex y": (apex.y, ref["apex_y"]),
        "apex xdot": (apex.xdot, ref["xdot"]),
        "apex pitch": (apex.pitch, ref["apex_pitch"]),
        "apex pitch_rate": (apex.pitch_rate, ref["pitch_rate"]),
        "apex_time": (res.apex_time, ref["apex_time"]),
    }  # fmt: skip
    differences = _differences(pairs)
    assert all(difference <= AGREE for difference in differences.values()), differences


def test_stance_energy_flows_agree_with_the_reference_whose_balance_holds(case):
    _, _, _, res, ref = case
    relative = {
        name: abs(getattr(res.energy, name) - ref[name]) / abs(ref[name])
        for name in ("hip_work", "damping_loss", "spring_loss")
    }
    print("relative |model - reference| of the energies:", relative)
    assert relative["hip_work"] <= AGREE and relative["damping_loss"] <= AGREE, relative
    # The spring loss k (r_lo - r0)^2 / 2 follows from r_lo (checked to 1e-9 m above): to k |r_lo - r0| 1e-9.
    assert abs(res.energy.spring_loss - ref["spring_loss"]) <= K * abs(ref["r"] - R0) * AGREE
    # The reference's own balance: E_lo - E_td = hip work - damper loss (J phidot^2 / 2 included).
    imbalance = ref["energy_lo"] - ref["energy_td"] - (ref["hip_work"] - ref["damping_loss"])
    print("reference energy imbalance / E_td:", imbalance / ref["energy_td"])
    assert abs(imbalance) <= 1e-10 * ref["energy_td"]


@pytest.mark.parametrize("inertia", [2.0, 5.0, 50.0])
def test_a_hip_at_the_centre_of_mass_moves_the_com_as_the_point_mass_and_spins_by_minus_tau_over_j(inertia):
    """d = (0, 0): the centre of mass's stride is the point mass's whatever J, and J phi'' = -tau."""
    _, apex, command = CASES["hip at the centre of mass"]
    body = RigidBody(inertia=inertia, tip_limit=math.radians(60))
    rigid = apex_return_map(_params(body), apex, command)
    point = apex_return_map(_params(None), ApexState(y=apex.y, xdot=apex.xdot), command)
    assert rigid.failure is None and point.failure is None, (rigid.reason, point.reason)
    # The spin in closed form: phidot = w - (tau0 / J)(s - s^2 / (2 t_f)) on the ramp, constant after it.
    tau0, t_f = command.tau0, command.t_f
    s_lo = rigid.liftoff.t - rigid.touchdown.t
    assert s_lo > t_f
    rate_lo = apex.pitch_rate - tau0 * t_f / (2.0 * inertia)
    pitch_tf = apex.pitch + apex.pitch_rate * (rigid.touchdown.t + t_f) - tau0 * t_f**2 / (3.0 * inertia)
    pitch_lo = pitch_tf + rate_lo * (s_lo - t_f)
    ref = _reference(body, apex, command)
    pairs = {
        **{f"{name}": (getattr(rigid.liftoff, name), getattr(point.liftoff, name)) for name in (
            "t", "x", "y", "xdot", "ydot", "r", "theta", "rdot", "thetadot")},
        "apex y": (rigid.apex.y, point.apex.y),
        "apex xdot": (rigid.apex.xdot, point.apex.xdot),
        "lo pitch (closed form)": (rigid.liftoff.pitch, pitch_lo),
        "lo pitch_rate (closed form)": (rigid.liftoff.pitch_rate, rate_lo),
        "reference lo pitch (closed form)": (ref["pitch"], pitch_lo),
        "reference lo pitch_rate (closed form)": (ref["pitch_rate"], rate_lo),
    }  # fmt: skip
    differences = _differences(pairs)
    assert all(difference <= AGREE for difference in differences.values()), differences


@pytest.mark.parametrize("name", list(CASES))
def test_the_reference_mirrors_a_mirrored_start(name):
    """x -> -x flips xdot, pitch, pitch rate, hip_x, theta and tau: the reference's stride mirrors."""
    body, apex, command = CASES[name]
    ref = _reference(body, apex, command)
    mirrored = reference_stride(
        body.inertia,
        (-body.hip_x, body.hip_y),
        (apex.y, -apex.xdot, -apex.pitch, -apex.pitch_rate),
        -command.touchdown_angle,
        -command.tau0,
        command.t_f,
    )
    flipped = set("toe_x td_x td_pitch x xdot pitch pitch_rate theta thetadot apex_pitch".split())
    for key, value in ref.items():
        expected = -value if key in flipped else value
        assert mirrored[key] == pytest.approx(expected, rel=1e-12, abs=1e-12), key
