"""The SI <-> dimensionless boundary (eq. 24) against the paper's numbers and as exact inverses."""

from __future__ import annotations

import numpy as np
import pytest

from tdslip_ros.model import units
from tdslip_ros.model.params import HopperParams

HUMAN = HopperParams.from_dimensionless(kbar=36.0, zeta0=0.08, m=80.0, r0=1.0)


def test_paper_speed_example() -> None:
    # Section IV.B: xdotbar = 1.5 "corresponds to roughly 4.7 m/s for an average sized human".
    assert units.speed_from_bar(HUMAN, 1.5) == pytest.approx(4.7, abs=0.01)


def test_scales_follow_eq_24() -> None:
    small = HopperParams(m=2.0, k=500.0, r0=0.25, c=3.0, g=9.0)
    assert units.height_to_bar(small, 0.5) == pytest.approx(2.0)
    assert units.speed_to_bar(small, 1.5) == pytest.approx(1.0)
    assert units.energy_to_bar(small, 4.5) == pytest.approx(1.0)
    assert units.torque_to_bar(small, 9.0) == pytest.approx(2.0)
    assert units.power_to_alpha(small, 27.0) == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("to_bar", "from_bar"),
    [
        (units.height_to_bar, units.height_from_bar),
        (units.speed_to_bar, units.speed_from_bar),
        (units.energy_to_bar, units.energy_from_bar),
        (units.torque_to_bar, units.torque_from_bar),
        (units.power_to_alpha, units.power_from_alpha),
    ],
)
def test_conversions_are_inverse_on_arrays(to_bar, from_bar) -> None:  # type: ignore[no-untyped-def]
    values = np.linspace(-3.0, 7.0, 11)
    np.testing.assert_allclose(from_bar(HUMAN, to_bar(HUMAN, values)), values, rtol=1e-15, atol=1e-15)
