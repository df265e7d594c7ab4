"""The paper's hopper, declared once: every figure, study, default and benchmark that means "the
paper's" uses these values.

The human-like hopper of the paper's examples: kbar = k r0/(m g) = 36 and zeta0 = c/(2 sqrt(m k)) =
0.08 (its sections III-IV), with m = 80 kg, r0 = 1 m and g = 9.81 m/s^2.
"""

from __future__ import annotations

from tdslip_ros.model.params import HUMAN_LIKE_LEG_LENGTH, HUMAN_LIKE_MASS, HopperParams

PAPER_KBAR = 36.0
PAPER_ZETA0 = 0.08
PAPER_PARAMS = HopperParams.from_dimensionless(
    kbar=PAPER_KBAR, zeta0=PAPER_ZETA0, m=HUMAN_LIKE_MASS, r0=HUMAN_LIKE_LEG_LENGTH
)
"""The paper's hopper in SI."""
