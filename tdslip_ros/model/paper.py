"""The paper's hopper, declared once: every figure, study, default and benchmark that means "the
paper's" uses these values.

The human-like hopper of the paper's examples: kbar = k r0/(m g) = 36 and zeta0 = c/(2 sqrt(m k)) =
0.08 (its sections III-IV), with m = 80 kg, r0 = 1 m and g = 9.81 m/s^2.
"""

from __future__ import annotations

from tdslip_ros.model.params import HUMAN_LIKE_LEG_LENGTH, HUMAN_LIKE_MASS, HopperParams, RigidBody

PAPER_KBAR = 36.0
PAPER_ZETA0 = 0.08
PAPER_PARAMS = HopperParams.from_dimensionless(
    kbar=PAPER_KBAR, zeta0=PAPER_ZETA0, m=HUMAN_LIKE_MASS, r0=HUMAN_LIKE_LEG_LENGTH
)
"""The paper's hopper in SI."""

UPRIGHT_TRUNK_GYRATION_RADIUS, UPRIGHT_TRUNK_HIP_Y = 0.3, -0.2
"""Not the paper's, but on its hopper: the suite's example of a freely rotating body (the paper's section VI,
docs/rotating_body.md), an upright trunk of radius of gyration 0.3 m [m] standing on its hip 0.2 m below the
centre of mass [m]. ``tdslip body``'s strides and GRF, and the nodes' ``body: rigid``, use it."""
UPRIGHT_TRUNK = RigidBody.from_gyration(
    PAPER_PARAMS.m, UPRIGHT_TRUNK_GYRATION_RADIUS, hip_y=UPRIGHT_TRUNK_HIP_Y
)
"""The upright trunk on the paper's hopper (inertia 7.2 kg m^2)."""
