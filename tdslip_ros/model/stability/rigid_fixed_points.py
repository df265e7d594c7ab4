"""Fixed points of the 4-D apex return map of a hopper with a rigid body, (y, xdot, phi, phidot) -> the next
apex's, on the exact map, with their eigenvalues (docs/rotating_body.md).

The map is closed by an apex policy: any callable (hopper, apex) -> command, such as
:class:`tdslip_ros.model.policies.posture.HipEnergyRegulation`, or one that returns a
:class:`.stance_laws.StanceFeedback` (:class:`tdslip_ros.model.policies.virtual_pivot.VirtualPivot`). A
sampled law is sampled from touchdown on (the stride's first sample at the touchdown instant): on the
plant's absolute grid the touchdown's phase in the tick would make the map jump by a sample's worth as
the state moves, and a fixed point would not be one to 1e-9.

Fixed points are found by scipy.optimize.root (``hybr``) on P(x) - x; a stride that fails counts as a
residual of 1e3 in every component, so the solver steps back. The Jacobian is central differences of
step ``step`` on each component: with the exact map's 1e-12 accuracy and the default step 1e-6, its
entries are good to about 1e-6.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import root

from tdslip_ros.model import body_dynamics
from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError, StanceCommand
from tdslip_ros.model.plant.exact_map import StrideResult, apex_return_map
from tdslip_ros.model.plant.stance_laws import StanceFeedback

ApexPolicy = Callable[[HopperParams, ApexState], StanceCommand | StanceFeedback]
"""The command for a stride from its apex, given the hopper."""

FAILED_RESIDUAL = 1e3
"""The residual of each component of P(x) - x when the stride from x fails."""


def apex_vector(apex: ApexState) -> FloatArray:
    """(y [m], xdot [m/s], pitch [rad], pitch_rate [rad/s])."""
    return np.array([apex.y, apex.xdot, apex.pitch, apex.pitch_rate])


def closed_loop_stride(params: HopperParams, policy: ApexPolicy, apex: ApexState) -> StrideResult:
    """One stride of the exact map from ``apex`` under the policy's command (a sampled law sampled from
    touchdown on: module docstring)."""
    body = params.body
    if body is None:
        raise ParameterError("the 4-D apex map needs a hopper with a rigid body (HopperParams.body)")
    command = policy(params, apex)
    apex_time = 0.0
    if isinstance(command, StanceFeedback):
        cos_td = math.cos(command.touchdown_angle)
        t_td = body_dynamics.rigid_touchdown_time(params, body, apex.y, apex.pitch, apex.pitch_rate, cos_td)
        apex_time = 0.0 if t_td is None else -t_td
    return apex_return_map(params, apex, command, apex_time=apex_time)


@dataclass(frozen=True)
class RigidFixedPoint:
    """A fixed point of the 4-D apex map: ``apex`` (None when none was found), the map's Jacobian there
    (4 x 4, NaN without a fixed point) and its eigenvalues, the largest |P(x) - x| component (``residual``),
    and scipy's success flag and message."""

    apex: ApexState | None
    jacobian: FloatArray
    eigenvalues: npt.NDArray[np.complex128]
    residual: float
    success: bool
    message: str

    @property
    def spectral_radius(self) -> float:
        """The largest |eigenvalue|; NaN without a fixed point."""
        return float(np.max(np.abs(self.eigenvalues)))

    @property
    def stable(self) -> bool:
        """A fixed point whose eigenvalues all lie inside the unit circle."""
        return self.apex is not None and self.spectral_radius < 1.0


def rigid_fixed_point(
    params: HopperParams,
    policy: ApexPolicy,
    guess: ApexState,
    *,
    tolerance: float = 1e-9,
    step: float = 1e-6,
) -> RigidFixedPoint:
    """The fixed point of the policy's 4-D apex map nearest ``guess`` that scipy's ``hybr`` finds, accepted
    when every component of P(x) - x is within ``tolerance``; its Jacobian by central differences of
    ``step`` (module docstring)."""

    def next_apex(state: FloatArray) -> FloatArray | None:
        try:
            apex = ApexState(*(float(v) for v in state))
            result = closed_loop_stride(params, policy, apex)
        except ParameterError:  # beyond the limits, or a policy without a command
            return None
        return None if result.apex is None else apex_vector(result.apex)

    def gap(state: FloatArray) -> FloatArray:
        following = next_apex(state)
        return np.full(4, FAILED_RESIDUAL) if following is None else following - state

    solution = root(gap, apex_vector(guess), method="hybr", options={"xtol": 1e-12})
    residual = float(np.max(np.abs(gap(solution.x))))
    nothing = np.full((4, 4), np.nan)
    if residual > tolerance:
        message = (
            f"no fixed point within {tolerance!r}: largest |P(x) - x| {residual:.3g} ({solution.message})"
        )
        return RigidFixedPoint(None, nothing, np.full(4, np.nan + 0j), residual, False, message)
    columns = []
    for unit in np.eye(4):
        ahead, behind = next_apex(solution.x + step * unit), next_apex(solution.x - step * unit)
        if ahead is None or behind is None:
            message = "a stride next to the fixed point fails: no Jacobian"
            return RigidFixedPoint(
                ApexState(*solution.x), nothing, np.full(4, np.nan + 0j), residual, False, message
            )
        columns.append((ahead - behind) / (2.0 * step))
    jacobian = np.column_stack(columns)
    apex = ApexState(*(float(v) for v in solution.x))
    eigenvalues = np.linalg.eigvals(jacobian).astype(np.complex128)
    return RigidFixedPoint(apex, jacobian, eigenvalues, residual, True, str(solution.message))
