"""The paper's stance policies as pure functions: apex state(s), parameters, targets -> stance command arrays.

Every policy returns :class:`~tdslip_ros.model.arrays.CommandArrays` (touchdown angle [rad], ramp torque
tau0 [N m], ramp duration t_f [s]) broadcast over the inputs; ``.command()`` turns one lane into a validated
:class:`~tdslip_ros.model.params.StanceCommand`. A returned command always maps, in the map the policy
planned with, to a valid stride: where no such command exists the lane's fields are NaN and its
``no_command`` code names the reason (:class:`~tdslip_ros.model.arrays.NoCommand`: the leg cannot be
placed, no liftoff, a predicted fall or reversal, no forward torque solution), and ``.command()`` raises
:class:`~tdslip_ros.model.arrays.NoCommandError` with it. Touchdown angles are planned only where
:func:`~tdslip_ros.model.dynamics.can_place_leg` holds, the test the plant applies to every command.

``t_f`` is the liftoff time that the map predicts *for the returned command itself* (a fixed point
t_f = t_lo(t_f), since the torque correction of p_hat depends on t_f), so the map evaluated with the command
is exactly the map the policy planned with. The ideal regulator :func:`exact_energy_regulation`
(``energy_exact``) plans on the exact plant's map instead, with t_f the stance duration the plant produces.

Energy regulation has two torque roots. The hip energy E_tau = tau0 e(tau0), e the ramp-weighted mean
angular rate, is close to quadratic in tau0 because the torque's own momentum correction moves e; the
root the policies return is the *forward* one, where the body swings forward on average (e < 0, so forward
thrust tau0 < 0 does positive work). The other root drives the body backward and the map rejects it.

The torque-based policies are complex-step safe (for
:func:`~tdslip_ros.model.analytic.closed_loop.map_jacobian`).

Implementation. Each analytic policy is a compiled kernel of one lane (:mod:`.controller_kernels`,
:mod:`.deadbeat_kernels`) on the analytic map's own lane kernels; the functions here broadcast their inputs
and run it in a compiled loop over the lanes, so one apex costs a call into compiled code and a batch costs
one loop. A lane's command does not depend on the other lanes of its batch. The policies by name, with
their settings, are :mod:`.registry`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from tdslip_ros.model import units
from tdslip_ros.model.analytic.apex_map import (
    LiftoffMethod,
    SpeedSource,
    approximate_map,
    check_corrections,
    map_variant_code,
    validate_angle,
)
from tdslip_ros.model.analytic.closed_loop import fixed_command, map_jacobian
from tdslip_ros.model.arrays import (
    HAS_COMMAND,
    Array,
    ArrayLike,
    CommandArrays,
    Lanes,
    ParamArrays,
    elementwise,
)
from tdslip_ros.model.dynamics import apex_energy
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.policies.controller_kernels import (
    COMMAND_ROWS,
    FIXED_POINT_ITERATIONS,
    POWER_RULE,
    TORQUE_RULE,
    foot_placement_lanes,
    lane_admissible_angles,
    neutral_angle_of,
    planned_lanes,
    regulated_lanes,
)
from tdslip_ros.model.policies.deadbeat_kernels import deadbeat_lanes

EXACT_ENERGY_TOLERANCE = 1e-11
"""Dimensionless energy E/(m g r0) to which energy_exact meets its target on the exact map."""
EXACT_STANCE_TOLERANCE = 1e-10
"""|t_f - stance duration| in units of sqrt(m/k) to which energy_exact ends the ramp at liftoff."""
EXACT_ITERATIONS = 12
"""Bound on energy_exact's Newton steps (3-4 from the analytic plan)."""
EXACT_JACOBIAN_STEP = 1e-6
"""Forward-difference step of energy_exact's Jacobian in the scaled (tau0, t_f): large against the exact
map's integration error (~1e-12), small against the curvature."""
EXACT_MAP_TOLERANCE = 1e-12
"""rtol = atol of the exact map energy_exact plans on (the batched engine's default)."""
FOOT_PLACEMENT_KP = 0.06
"""rad/(m/s): :func:`apex_foot_placement`'s gain on the speed error."""
FOOT_PLACEMENT_KD = 0.03
"""rad/(m/s): :func:`apex_foot_placement`'s gain on the speed change over a stride."""


def _require_at_least(name: str, value: int, least: int) -> None:
    if value < least:
        raise ParameterError(f"{name} must be at least {least}, got {value!r}")


def _commands(lanes: Lanes, block: Array) -> CommandArrays:
    angle, tau0, t_f = (lanes.shaped(row) for row in block[:3])
    return CommandArrays(angle, tau0, t_f, no_command=lanes.codes(block[3]))


def _planned(
    params: ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    angle: ArrayLike,
    value: ArrayLike,
    rule: int,
    check: bool,
    corrections: int,
    liftoff: LiftoffMethod,
    speed: SpeedSource,
) -> CommandArrays:
    check_corrections(corrections)
    code = map_variant_code(liftoff, speed)
    lanes = Lanes.of(params, y, xdot, angle, value)
    block = lanes.rows(COMMAND_ROWS)
    lanes.run(planned_lanes, rule, check, corrections, code, block)
    return _commands(lanes, block)


def ramp_to_liftoff(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    angle: ArrayLike,
    tau0: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> CommandArrays:
    """A given touchdown angle and ramp torque tau0, with t_f the liftoff time the map predicts for them.

    Not a policy but the paper's ramp for studies of the map itself (analytic_accuracy): the command is
    returned wherever t_f exists, also where the map then predicts a fall or a reversal, so that the
    failures of the analytic and the exact map can be compared.
    """
    return _planned(
        ParamArrays.of(params), y, xdot, angle, tau0, TORQUE_RULE, False, corrections, liftoff, speed
    )


def fixed_power(
    params: HopperParams,
    y: ArrayLike,
    xdot: ArrayLike,
    beta: ArrayLike,
    alpha: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> CommandArrays:
    """Open-loop regime of section III: theta_td = beta, tau0 = C/thetadot_td (eq. 26), t_f = predicted t_lo.

    ``alpha`` is the dimensionless touchdown power C/(m g sqrt(g r0)); C = tau0 thetadot_td > 0 is the hip
    power at touchdown (thetadot_td < 0, so tau0 < 0: forward thrust). t_f is the paper's choice, the
    liftoff time the analytic map predicts, not the stance duration the plant will produce (on the exact
    plant the ramp then ends a little before or after liftoff; docs/paper.md quantifies the difference).
    """
    validate_angle(beta)
    power = units.power_from_alpha(params, np.asarray(alpha, dtype=float))
    return _planned(
        ParamArrays.of(params), y, xdot, beta, power, POWER_RULE, True, corrections, liftoff, speed
    )


def energy_regulation(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    beta: ArrayLike,
    target_energy: ArrayLike | None = None,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
    max_iterations: int = FIXED_POINT_ITERATIONS,
) -> CommandArrays:
    """Energy regulation of section IV.A: theta_td = beta and tau0 with E_tau = E_loss (eq. 32), t_f = t_lo.

    With ``target_energy`` E* [J], E_tau = E_loss + (E* - E_a): the energy of the next apex predicted by the
    analytic map is E* (this is the regulator the exact-plant studies use, with the first stride's energy as
    E*, so that prediction errors do not accumulate). Without it, E* = E_a (the paper's eq. 32).
    For a given stance E_tau is linear in tau0, so each fixed-point step solves that linear equation; of
    the two roots the forward one is returned (:func:`~.controller_kernels.lane_regulated_plan`). Lanes
    not solved in ``max_iterations`` (at least 1) Newton steps get no_solution.
    """
    _require_at_least("max_iterations", max_iterations, 1)
    validate_angle(beta)
    check_corrections(corrections)
    code = map_variant_code(liftoff, speed)
    params = ParamArrays.of(params)
    target = 0.0 if target_energy is None else target_energy
    lanes = Lanes.of(params, y, xdot, beta, target)
    block = lanes.rows(COMMAND_ROWS)
    has_target = target_energy is not None
    lanes.run(regulated_lanes, has_target, corrections, code, max_iterations, block)
    return _commands(lanes, block)


def exact_energy_regulation(
    params: HopperParams,
    y: ArrayLike,
    xdot: ArrayLike,
    beta: ArrayLike,
    target_energy: ArrayLike | None = None,
    corrections: int = 1,
) -> CommandArrays:
    """The ideal regulator ``energy_exact``: theta_td = beta and the (tau0, t_f) with which the exact plant's
    next apex has the energy E* [J] (E* = E_a without a target) to EXACT_ENERGY_TOLERANCE, t_f being the
    stance duration the plant itself produces with that command (the ramp ends at the exact liftoff).

    Newton's method on the exact map (DOP853 at EXACT_MAP_TOLERANCE, one lane at a time in compiled code:
    :func:`~.exact_regulation_kernels.exact_regulation_lanes`) for x = (tau0, t_f) scaled as in
    :func:`~.controller_kernels.lane_plan` and the residuals ((E' - E*)/(m g r0), T_stance/sqrt(m/k) - x_1);
    its Jacobian by forward differences. It starts from :func:`energy_regulation`'s forward root
    (``corrections`` of its map) and returns a command only where the exact map, evaluated with that very
    command, succeeds and meets both tolerances. Lanes where the analytic plan has no command keep its
    reason, lanes where the exact map fails at an iterate get that failure's, and lanes not converged in
    EXACT_ITERATIONS get no_solution. A plan costs about 3 x 4 exact strides (a few tenths of a millisecond).
    An apex the analytic plan has no command for, one beyond the hopper's limits among them, keeps its reason
    (no exception). The gap between ``energy`` and ``energy_exact`` is what the analytic approximation costs.
    """
    # Imported here: the exact kernels import scipy.integrate, which only this policy needs, so that a
    # controller node of the other policies starts without it (its DDS discovery races the recorder's).
    from tdslip_ros.model.limits import validate_lanes
    from tdslip_ros.model.plant.stride_kernels import default_limits, kernel_rows
    from tdslip_ros.model.policies.exact_regulation_kernels import Newton, exact_regulation_lanes

    arrays = ParamArrays.of(params)
    y_, xdot_, beta_ = (np.asarray(value) for value in (y, xdot, beta))
    start = energy_regulation(arrays, y_, xdot_, beta_, target_energy, corrections)
    shape = np.shape(start.tau0)
    goal = (
        np.asarray(apex_energy(arrays.m, arrays.g, y_, xdot_))
        if target_energy is None
        else np.asarray(target_energy, dtype=float)
    )
    y_l, xdot_l, angle, goal_bar, tau0, t_f = (
        np.array(np.broadcast_to(np.real(value), shape), dtype=float).ravel()
        for value in (y_, xdot_, beta_, goal / units.energy_scale(params), start.tau0, start.t_f)
    )
    assert start.no_command is not None
    reason = np.array(np.broadcast_to(start.no_command, shape), dtype=np.int64).ravel()
    planned = reason == HAS_COMMAND
    limits = default_limits(params)
    validate_lanes(limits, y_l[planned], xdot_l[planned], angle[planned], ())
    hopper, bounds = kernel_rows(limits)
    newton = Newton(EXACT_ENERGY_TOLERANCE, EXACT_STANCE_TOLERANCE, EXACT_ITERATIONS, EXACT_JACOBIAN_STEP)
    exact_regulation_lanes(
        hopper, bounds, y_l, xdot_l, angle, goal_bar, tau0, t_f, EXACT_MAP_TOLERANCE, newton, reason
    )
    angle_out = np.where(reason == HAS_COMMAND, angle, np.nan).reshape(shape)
    return CommandArrays(angle_out, tau0.reshape(shape), t_f.reshape(shape), no_command=reason.reshape(shape))


def admissible_angles(params: HopperParams | ParamArrays, y: ArrayLike) -> tuple[Array, Array]:
    """Touchdown angles that place the leg from apex height y: (arccos(min((y - d)/r0, 1)), pi/2) less
    ANGLE_MARGIN, d = dynamics.placement_clearance (the angles dynamics.can_place_leg accepts).

    This is eq. 34's interval (-pi/2, pi/2) cut to forward running (StanceCommand's (0, pi/2)) and to
    feasible leg placement (y - d >= r0 cos(theta_td)). The interval is empty (lower > upper) for an apex
    below d.
    """
    params = ParamArrays.of(params)
    lower, upper = elementwise(lane_admissible_angles, [float, float], params.r0, params.g, np.real(y))
    return lower, upper


@lru_cache(maxsize=8)
def _scan_fractions(grid: int) -> Array:
    """Deadbeat's scan angles as fractions of the admissible interval (read-only, being shared)."""
    fractions = np.linspace(0.0, 1.0, grid)
    fractions.flags.writeable = False
    return fractions


def deadbeat(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    target_y: ArrayLike,
    target_xdot: ArrayLike,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    grid: int = 32,
    angle_tolerance: float = 1e-9,
    *,
    speed: SpeedSource = "energy",
) -> CommandArrays:
    """Deadbeat control by inversion of the analytic map (section V.A, eqs. 33-34).

    The torque supplies the energy of the target apex in one stride, E_tau = dE + E_loss (eq. 33, the
    energy regulation with E* = m g y* + m xdot*^2/2), solved jointly with t_f = t_lo for every candidate
    angle. The touchdown angle minimises f = r^2, r(theta) = xdot_next(theta) - xdot* (eq. 34), over the
    admissible interval (:func:`admissible_angles`). Since the map's next energy is then E* exactly,
    reaching xdot* also means reaching y*. Angles where the map fails count as f = +inf.

    * Scan: energy regulation and the map at ``grid`` angles across the interval. It only ranks the angles,
      so its solve stops after DEADBEAT_SCAN_ITERATIONS Newton steps and angles not solved by then count as
      failed (the angles towards pi/2, which have no solution, would otherwise iterate to
      FIXED_POINT_ITERATIONS).
    * Refinement, from the best scan angle in the bracket of its neighbours, down to ``angle_tolerance``
      rad: Newton's method on (theta, tau0, t_f) at once, the map evaluated at the point and its three
      forward-difference shifts per step (:func:`.deadbeat_kernels.linearise`). The angle step is Newton's for
      f'/2 = r r' = 0, ``delta = -r r'/(r'^2 + r r'')`` with r' taken along the torque solution and r'' from
      a secant of r'. Where the target is reachable (r = 0) this is Newton's method on r (quadratic
      convergence); where it is not, the secant method on r' = 0 (the extremum of xdot_next). A step that
      would leave the bracket is replaced by bisection, and the sign of f' at each new angle (a failed
      angle counts as uphill) shrinks the bracket. The torque takes the Newton step of its fixed point for
      the new angle, so both converge together; the result solves that fixed point to
      FIXED_POINT_TOLERANCE, like :func:`energy_regulation` at the returned angle.

    The returned command is the refined one where the map accepts it, else the best scanned one (which
    it accepts). Lanes where every scanned angle fails get no_solution (leg_placement where no angle can
    place the leg). ``grid`` must be at least 2. Not complex-step safe (real parts are used).
    """
    _require_at_least("grid", grid, 2)
    check_corrections(corrections)
    code = map_variant_code(liftoff, speed)
    params = ParamArrays.of(params)
    lanes = Lanes.of(params, *(np.real(v) for v in (y, xdot, target_y, target_xdot)))
    block = lanes.rows(COMMAND_ROWS)
    lanes.run(deadbeat_lanes, _scan_fractions(grid), angle_tolerance, corrections, code, block)
    return _commands(lanes, block)


def neutral_angle(params: HopperParams | ParamArrays, xdot: ArrayLike) -> Array:
    """Raibert's neutral touchdown angle, toe half a stance's travel ahead: sin(theta_n) = xdot T_s/(2 r0).

    T_s = pi sqrt(m/k) is the half period of the leg spring, the usual estimate of the stance time.
    """
    params = ParamArrays.of(params)
    return elementwise(neutral_angle_of, [complex], params.m, params.k, params.r0, xdot)[0]


def apex_foot_placement(
    params: HopperParams | ParamArrays,
    y: ArrayLike,
    xdot: ArrayLike,
    previous_xdot: ArrayLike,
    target_y: ArrayLike,
    target_xdot: ArrayLike,
    kp: ArrayLike = FOOT_PLACEMENT_KP,
    kd: ArrayLike = FOOT_PLACEMENT_KD,
    corrections: int = 1,
    liftoff: LiftoffMethod = "paper",
    *,
    speed: SpeedSource = "energy",
) -> CommandArrays:
    """Apex-level foot placement: the touchdown angle steers the speed, the ramp torque the energy, both
    decided once per stride at the apex (no feedback in stance). It is not the baseline of the paper's
    ref. 36, which acts on speed through the hip torque during stance
    (:class:`~tdslip_ros.model.policies.stance_pd.StancePDSpeedEnergy`).

    * Speed, through the touchdown angle (Raibert-style foot placement, discrete PD over strides)::

          theta_td = theta_n(xdot) + kp (xdot - xdot*) + kd (xdot - xdot_prev)

      with theta_n from :func:`neutral_angle`, gains in rad/(m/s) (scalars, or one per lane), clipped into
      :func:`admissible_angles`. Running too fast places the foot further ahead, which brakes.
      ``previous_xdot`` is the speed at the previous apex (pass ``xdot`` on the first stride).
    * Height, through the energy: tau0 from the analytic map so that the next apex has the energy of the
      target apex, E* = m g y* + m xdot*^2/2 (:func:`energy_regulation` with that target).

    Unlike :func:`deadbeat`, the angle ignores the map, so height and speed converge only over strides.
    """
    check_corrections(corrections)
    code = map_variant_code(liftoff, speed)
    params = ParamArrays.of(params)
    lanes = Lanes.of(params, y, xdot, previous_xdot, target_y, target_xdot, kp, kd)
    block = lanes.rows(COMMAND_ROWS)
    lanes.run(foot_placement_lanes, corrections, code, block)
    return _commands(lanes, block)


def warm_up(params: HopperParams | None = None, complex_step: bool = True, exact_plant: bool = True) -> None:
    """Load the compiled kernels of the analytic map and of every analytic policy, for one apex at a time
    as the controller node plans (and with ``complex_step`` for the complex step of map_jacobian too; with
    ``exact_plant`` the compiled exact stride and energy_exact's plan on it,
    :mod:`.exact_regulation_kernels`), compiling those not yet in the cache (:mod:`tdslip_ros.model.compiled`;
    about a minute for all of them, once). The controller node calls it before it subscribes to the apex, so
    that its first answer
    is not late; ``./run.sh setup`` calls it so that the first node or test does not compile."""
    params = PAPER_PARAMS if params is None else params
    y, xdot, beta = 1.1, 4.5, np.radians(26.0)
    for liftoff in ("paper", "force_root"):
        approximate_map(params, y, xdot, StanceCommand(beta, -500.0, 0.15), liftoff=liftoff)
    energy = float(apex_energy(params.m, params.g, y, xdot))
    energy_regulation(params, y, xdot, beta)
    energy_regulation(params, y, xdot, beta, energy)
    fixed_power(params, y, xdot, beta, 1.5)
    ramp_to_liftoff(params, y, xdot, beta, -500.0)
    deadbeat(params, y, xdot, y, xdot)
    apex_foot_placement(params, y, xdot, xdot, y, xdot)
    if exact_plant:
        from tdslip_ros.model.plant.stride_kernels import (
            apex_stride,
        )  # scipy.integrate: only here (see energy_exact)

        exact_energy_regulation(params, y, xdot, beta)
        apex_stride(params, ApexState(y, xdot), StanceCommand(beta, -500.0, 0.15))
    if complex_step:
        for policy in (
            lambda p, y_, x_: energy_regulation(p, y_, x_, beta),
            lambda p, y_, x_: fixed_power(params, y_, x_, beta, 1.5),
            fixed_command(StanceCommand(beta, -500.0, 0.15)),
        ):
            map_jacobian(params, np.asarray(y), np.asarray(xdot), policy)
