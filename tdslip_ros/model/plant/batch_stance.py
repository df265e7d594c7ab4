"""The stance of the batched engine's lanes (:mod:`.batch`), from touchdown to each lane's end, on the
compiled stance integrator of :mod:`.stance_kernel` (the compiled stride's too), one lane after the other
(:func:`.stance_kernel.integrate_lanes`; a rigid body's 8-value states on
:func:`.stance_kernel.integrate_rigid_lanes`).

Lanes under torque ramps go through it in one call. Lanes under stance feedback (:mod:`.stance_laws`) go
sample by sample: each lane holds its last sampled torque until its next sample instant, where the
integrator stops it; the law is then evaluated here, with numpy, on the lanes that stopped, and they resume
with the torque it set (a rigid body's law sees its pitch and pitch rate). A lane's result depends on that
lane alone.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.params import HopperParams
from tdslip_ros.model.plant.stance_kernel import (
    STANCE_STOP,
    first_step,
    hopper_row,
    integrate_lanes,
    integrate_rigid_lanes,
)
from tdslip_ros.model.plant.stance_laws import StanceLaw, StanceSample, clip_torque, first_sample

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


def _at_touchdown(params: HopperParams, lanes: int) -> tuple[FloatArray, FloatArray, IntArray]:
    """The lanes' time since touchdown (0), first trial steps and (yet unset) outcomes."""
    return np.zeros(lanes), np.full(lanes, first_step(params)), np.empty(lanes, dtype=np.int64)


def _integrator(params: HopperParams) -> Callable[..., None]:
    """The compiled lane loop of the hopper's stance: the point mass's, or a rigid body's."""
    return integrate_lanes if params.body is None else integrate_rigid_lanes


def ramp_stance(
    params: HopperParams,
    y: FloatArray,
    tau0: FloatArray,
    t_f: FloatArray,
    tau_max: FloatArray | None,
    t_limit: float,
    rtol: float,
    atol: float,
) -> tuple[IntArray, FloatArray]:
    """Integrate lanes from their touchdown states y (lanes, STATE_SIZE; RIGID_STATE_SIZE with a rigid body)
    to their ends under the ramps of eq. 18 (tau0 [N m], t_f [s]) saturated at tau_max [N m] (inf or None:
    never). Returns per lane the outcome (stance_kernel.STANCE_*) and its time s since touchdown; y then
    holds the state there."""
    lanes = tau0.size
    s, h, outcome = _at_touchdown(params, lanes)
    never = np.full(lanes, math.inf)
    saturation = never if tau_max is None else tau_max
    _integrator(params)(
        hopper_row(params),
        tau0,
        t_f,
        saturation,
        never,
        np.arange(lanes),
        float(t_limit),  # floats: an int would compile the kernels a second time
        float(rtol),
        float(atol),
        s,
        h,
        y,
        outcome,
    )
    assert not np.any(outcome == STANCE_STOP), "a ramp has no stop instant"
    return outcome, s


def feedback_stance(
    params: HopperParams,
    y: FloatArray,
    law: StanceLaw,
    period: float,
    t_touchdown: FloatArray,
    limit: FloatArray,
    tau_max: FloatArray | None,
    lane: IntArray,
    saturated: BoolArray,
    t_limit: float,
    rtol: float,
    atol: float,
) -> tuple[IntArray, FloatArray]:
    """:func:`ramp_stance` for lanes under the sampled ``law``: each lane holds the torque its law set at
    its last sample instant (zero before its first), clipped at ``limit``; its sample instants are the
    multiples of ``period`` on the absolute clock of its touchdown t_touchdown [s].

    ``lane`` indexes the law's per-lane fields; ``saturated`` (by that index, over every lane of the
    stride) records whether tau_max clipped a sample (tau_max None: no saturation)."""
    lanes = t_touchdown.size
    s, h, outcome = _at_touchdown(params, lanes)
    index: FloatArray = first_sample(t_touchdown, period)
    held = np.zeros(lanes)
    # The held torque is a ramp without end (t_f = inf holds tau0), clipped here rather than saturated.
    unbounded = np.full(lanes, math.inf)
    stop = index * period - t_touchdown

    def sample(at: IntArray) -> None:
        """The lanes ``at`` stand on their sample instants: the law sets the torque they hold next."""
        if not at.size:
            return
        pitch = () if params.body is None else (y[at, 6], y[at, 7])
        seen = StanceSample(
            index[at] * period, s[at], y[at, 0], y[at, 1], y[at, 2], y[at, 3], held[at], *pitch
        )
        tau = np.broadcast_to(np.asarray(law.torque(seen, lane[at]), dtype=np.float64), at.shape)
        if tau_max is not None:
            saturated[lane[at]] |= np.abs(tau) > tau_max[at]
        held[at] = clip_torque(tau, limit[at])
        index[at] += 1.0
        stop[at] = index[at] * period - t_touchdown[at]

    sample(np.flatnonzero(stop == 0.0))  # a touchdown on the grid is sampled at once
    stepping = np.arange(lanes)
    integrate = _integrator(params)
    while stepping.size:
        integrate(
            hopper_row(params),
            held,
            unbounded,
            unbounded,
            stop,
            stepping,
            float(t_limit),
            float(rtol),
            float(atol),
            s,
            h,
            y,
            outcome,
        )
        stepping = stepping[outcome[stepping] == STANCE_STOP]
        sample(stepping)
    return outcome, s
