"""A recording of a hopper that this suite did not write, as the analysis sees it: the samples on one time
base (:class:`MeasuredRun`) and the strides found in them (:class:`MeasuredStride`).

Everything here is SI and in the model's plane and sign convention (``docs/ARCHITECTURE.md``, the paper's
NOTES): x forward, y up, the leg angle theta from the vertical with the toe ahead of the body at touchdown
(theta > 0 there, decreasing through stance), a hip torque tau whose power is tau * thetadot. A bag's own
conventions (REP 103: z up) are converted where the bag is read, by the topic map, never later.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class MeasuredRun:
    """Samples of one recording on a uniform time base ``time`` [s], shape (n,).

    ``body_position`` and ``body_velocity`` are (n, 2): forward and vertical [m], [m/s].
    ``velocity_measured`` says whether the velocity was recorded (True) or differentiated from the position.
    The optional quantities are None where the map names no source for them: ``leg_length`` [m] and
    ``leg_angle`` [rad] of the leg from hip to toe; ``ground_force`` (n, 2) [N], the ground's force on the
    hopper; ``hip_torque`` [N m] on the leg; ``contact`` (n,) bool. ``sources`` names, for each quantity
    present, the topic it came from, or ``"inferred: <how>"``. ``in_gap`` (n,) bool marks the samples that
    lie in a gap of one of the sources (interpolated across it, not measured); None: no gaps known.
    """

    time: FloatArray
    body_position: FloatArray
    body_velocity: FloatArray
    velocity_measured: bool
    leg_length: FloatArray | None = None
    leg_angle: FloatArray | None = None
    ground_force: FloatArray | None = None
    hip_torque: FloatArray | None = None
    contact: BoolArray | None = None
    sources: tuple[tuple[str, str], ...] = ()
    in_gap: BoolArray | None = None


@dataclass(frozen=True)
class MeasuredStride:
    """One stride found in a :class:`MeasuredRun`: apex, touchdown, liftoff, next apex.

    The four are sample indices into the run's time base; the times are interpolated inside the sample
    (``apex_time`` etc., [s]). ``touchdown_angle`` [rad] is the leg's angle at touchdown in the model's
    convention. ``usable`` is False for a stride set aside, and ``reason`` says why (a gap, a phase missing);
    such a stride is never guessed.
    """

    apex_index: int
    touchdown_index: int
    liftoff_index: int
    next_apex_index: int
    apex_time: float
    touchdown_time: float
    liftoff_time: float
    next_apex_time: float
    touchdown_angle: float
    usable: bool = True
    reason: str = ""
