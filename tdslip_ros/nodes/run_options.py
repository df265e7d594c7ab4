"""The options of a ``tdslip run`` (:class:`RunOptions`), what each of its nodes is given for them (the
parameters' overrides, the bag's ``custom_data``), and their checks, made before any node process starts or
any file is written (:func:`check_options`). :mod:`.runner` runs them.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from rclpy.exceptions import InvalidTopicNameException
from rclpy.validate_full_topic_name import validate_full_topic_name

from tdslip_ros.interfaces import (
    custom_data_key,
    hopper_from_parameters,
    hopper_parameters,
    installed_parameters,
    perturbation_parameters,
    resolve,
)
from tdslip_ros.model import dynamics
from tdslip_ros.model.analytic.apex_map import ANALYTIC_MAPS
from tdslip_ros.model.limits import check_hopper
from tdslip_ros.model.params import ApexState, HopperParams, ParameterError
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.stepper_bounds import check_body
from tdslip_ros.model.policies.registry import (
    DEFAULT_APEX_HEIGHT,
    DEFAULT_APEX_SPEED,
    DEFAULT_STANCE_TOUCHDOWN_ANGLE,
    DEFAULT_TOUCHDOWN_ANGLE,
    FIXED_ANGLE_POLICIES,
    LEARNED,
    POLICIES,
    POSTURE,
    STANCE_FEEDBACK_POLICIES,
    PolicyError,
    check_policy_file,
)
from tdslip_ros.nodes import (
    controller_node,
    isolation,
    parameters,
    plant_parameters,
    stance_controller_node,
    topics,
)
from tdslip_ros.nodes.answers import ANSWER_SUBSCRIBERS, PLANT_AND_RECORDER
from tdslip_ros.nodes.plant_parameters import CLOCK_MODES
from tdslip_ros.reporting.output import OutputError, check_output_directory


class RunError(RuntimeError):
    """The suite could not run or record (a node did not start, crashed, or lost messages). When a node
    died mid-run, ``published`` holds what had been published, and ``recorded`` what the finalised
    bag holds (None if it could not be finalised), both by topic."""

    published: dict[str, int] | None = None
    recorded: dict[str, int] | None = None
    recoverable: dict[str, int] | None = None
    """For a bag left unfinalised: what ``tdslip recover`` gets back, by topic."""
    recorder_stopped: bool = False
    """The recorder is the node that ended first (a full disk, a crash, a kill)."""


class RunOptionError(RunError):
    """An option ``run`` cannot use, found before any node process starts or any file is written."""


@dataclass
class RunOptions:
    """What ``tdslip run`` runs. ``None`` leaves a setting to the installed YAML files, except
    ``target_energy``, which defaults to the energy of the initial apex (energy regulation then
    holds the hopper's energy)."""

    out: Path
    strides: int = 50
    """The run ends at this apex (0: never; then give a ``duration``)."""
    policy: str = "energy"
    mode: str = "lockstep"
    height: float = DEFAULT_APEX_HEIGHT
    speed: float = DEFAULT_APEX_SPEED
    touchdown_angle: float | None = None  # rad
    stance_touchdown_angle: float | None = None
    """The fixed touchdown angle of a stance-feedback policy [rad] (its setting of the same name)."""
    target_energy: float | None = None
    target_height: float | None = None
    target_speed: float | None = None
    analytic_map: str | None = None
    """The analytic map the controller's policy plans on (model.analytic.ANALYTIC_MAPS: ours, paper)."""
    policy_file: str | None = None
    """The learned policy's file (model.learned), absolute: the controller node reads it."""
    command_timeout: float | None = None
    realtime_priority: int | None = None
    """SCHED_FIFO priority of the realtime plant's tick (0: normal scheduling)."""
    realtime_cpu: int | None = None
    """The CPU the realtime plant's tick is pinned to (None: the plant's default, -1, any); one of this
    machine's."""
    record_clock: bool = False
    duration: float | None = None
    """Wall-time limit [s]: the run ends as complete when it is reached."""
    domain_id: int | None = None
    namespace: str = "/"
    """Namespace of the three nodes (``tdslip run --namespace /h1``: topics /h1/tdslip/...)."""
    perturbations: Perturbations = field(default_factory=Perturbations)
    """Terrain, sensing noise, placement error, torque limit and pushes for the plant; mismatch for the
    controller, whose hopper parameters become the plant's times its factors."""
    hopper: HopperParams | None = None
    """The hopper of the plant and of the controller's model alike (``tdslip run --hopper FILE``, --mass,
    ...); None: the installed plant.yaml's."""
    own_controller: bool = False
    """Start no controller: the user's own answers the apexes (``tdslip run --controller none``)."""
    controller_wait: float = 300.0
    """s to wait for the user's own controller to connect (own_controller only)."""


def _ros_value(value: object) -> str:
    """A -p override value in ROS's YAML syntax (floats keep their type, full precision)."""
    if isinstance(value, bool):
        return str(value).lower()
    return repr(value) if isinstance(value, float) else str(value)


def overrides_arguments(values: dict[str, object]) -> list[str]:
    arguments = []
    for name, value in values.items():
        if value is not None:
            arguments += ["-p", f"{name}:={_ros_value(value)}"]
    return arguments


def hopper_overrides(hopper: HopperParams | None) -> dict[str, object]:
    """The node parameters of ``hopper`` (none: the installed files'), the same for plant and controller."""
    if hopper is None:
        return {}
    return dict(hopper_parameters(hopper))


def plant_overrides(options: RunOptions) -> dict[str, object]:
    return {
        **hopper_overrides(options.hopper),
        **perturbation_parameters(options.perturbations),
        "clock_mode": options.mode,
        "max_strides": options.strides,
        "initial_height": options.height,
        "initial_forward_speed": options.speed,
        "initial_touchdown_angle": options.touchdown_angle,
        "command_timeout": options.command_timeout,
        "realtime_priority": options.realtime_priority,
        "realtime_cpu": options.realtime_cpu,
        "wait_for_recorder": True,
    }


def controller_overrides(options: RunOptions, params: HopperParams) -> dict[str, object]:
    target_energy = options.target_energy
    if (
        target_energy is None
    ):  # the initial apex's; a rigid body's hip's at pitch 0 (posture plans on the hip)
        hip_height = options.height + (0.0 if params.body is None else params.body.hip_y)
        target_energy = float(dynamics.apex_energy(params.m, params.g, hip_height, options.speed))
    model = hopper_overrides(options.hopper)
    mismatch = options.perturbations.mismatch
    if mismatch.active:  # the controller plans with another hopper
        planned = mismatch.controller_params(params)
        assert isinstance(planned, HopperParams)  # scalar factors
        check_hopper(planned)
        model = hopper_overrides(planned)
    # Its answers reach the recorder before it hears the first apex (answers.ANSWER_SUBSCRIBERS).
    common = {**model, ANSWER_SUBSCRIBERS.name: PLANT_AND_RECORDER}
    if options.policy in STANCE_FEEDBACK_POLICIES:
        return {
            **common,
            "policy": options.policy,  # stored with the run; the node's parameter is stance_policy
            "stance_policy": options.policy,
            "stance_touchdown_angle": options.stance_touchdown_angle,
            "target_energy": target_energy,
            "target_height": options.target_height,
            "target_speed": options.target_speed,
        }
    return {
        **common,
        "policy": options.policy,
        "touchdown_angle": options.touchdown_angle,
        "target_energy": target_energy,
        "target_height": options.target_height,
        "target_speed": options.target_speed,
        "analytic_map": options.analytic_map,
        "policy_file": options.policy_file,
    }


def run_custom_data(options: RunOptions, params: HopperParams) -> str:
    """The plant's and the controller's parameters of this run (installed defaults and overrides), as
    the recorder's ``custom_data`` (KEY=VALUE pairs): the bag then says how it was made."""
    pairs = []
    nodes = [("plant", plant_overrides(options))]
    if not options.own_controller:  # a controller of one's own stores nothing (tdslip analyze says so)
        nodes.append(("controller", controller_overrides(options, params)))
    for node, overrides in nodes:
        values = installed_parameters(f"{node}.yaml") | {k: v for k, v in overrides.items() if v is not None}
        pairs += [
            f"{custom_data_key(node, name)}={_ros_value(value)}" for name, value in sorted(values.items())
        ]
    return " ".join(pairs)


def check_options(options: RunOptions) -> None:
    """RunOptionError naming the first option ``run`` cannot use (nothing is created here)."""
    if options.mode not in CLOCK_MODES:
        raise RunOptionError(f"mode must be one of {', '.join(CLOCK_MODES)}, not {options.mode!r}")
    if options.policy not in (*POLICIES, *STANCE_FEEDBACK_POLICIES):
        choices = ", ".join((*POLICIES, *STANCE_FEEDBACK_POLICIES))
        raise RunOptionError(f"policy must be one of {choices}, not {options.policy!r}")
    if options.analytic_map is not None and options.analytic_map not in ANALYTIC_MAPS:
        raise RunOptionError(
            f"analytic map must be one of {', '.join(ANALYTIC_MAPS)}, not {options.analytic_map!r}"
        )
    if options.policy == LEARNED:
        if options.policy_file is None:
            raise RunOptionError("the learned policy needs its file (--policy-file)")
        if any(character.isspace() for character in options.policy_file):  # custom_data splits at spaces
            raise RunOptionError(f"the bag cannot name a file with spaces: {options.policy_file!r}")
        try:
            check_policy_file(options.policy_file)
        except PolicyError as error:
            raise RunOptionError(str(error)) from None
    try:
        perturbation_parameters(options.perturbations)  # per-lane values have no node parameters
    except ParameterError as error:
        raise RunOptionError(str(error)) from None
    if options.strides < 0:
        raise RunOptionError(f"strides must be 0 (no limit) or positive, not {options.strides}")
    if options.duration is not None and not (math.isfinite(options.duration) and options.duration > 0):
        raise RunOptionError(f"duration must be a positive number of seconds, not {options.duration}")
    if not (math.isfinite(options.controller_wait) and options.controller_wait > 0):
        raise RunOptionError(
            f"the wait for a controller must be positive seconds, not {options.controller_wait}"
        )
    if options.strides == 0 and options.duration is None:
        raise RunOptionError("a run without a stride limit (strides 0) needs a duration")
    if options.domain_id is not None and options.domain_id not in isolation.VALID_DOMAIN_IDS:
        valid = isolation.VALID_DOMAIN_IDS
        raise RunOptionError(f"domain id must be in {valid.start}-{valid.stop - 1}, not {options.domain_id}")
    try:
        validate_full_topic_name(resolve(topics.STATE, options.namespace))
    except InvalidTopicNameException:
        raise RunOptionError(f"{options.namespace!r} is not a valid ROS namespace") from None
    bag = Path(options.out)
    if bag.exists():
        raise RunOptionError(f"{bag} exists already; choose a new --out")
    try:
        check_output_directory(bag)
    except OutputError as error:
        raise RunOptionError(str(error)) from None
    if options.realtime_cpu not in (None, -1) and options.realtime_cpu not in os.sched_getaffinity(0):
        cpus = ", ".join(map(str, sorted(os.sched_getaffinity(0))))
        raise RunOptionError(f"realtime CPU {options.realtime_cpu} is not one this run may use ({cpus})")
    try:  # the plant's first: the controller's values derive from them (--height sets its target energy)
        parameters.check_values(plant_parameters.SPECS, plant_overrides(options))
    except ParameterError as error:
        raise RunOptionError(f"plant parameters: {error}") from None
    if options.hopper is not None:
        try:
            check_hopper(options.hopper)
        except ParameterError as error:
            raise RunOptionError(f"the hopper: {error}") from None
    hopper = options.hopper or hopper_from_parameters(installed_parameters("plant.yaml"))
    if options.policy == POSTURE and hopper.body is None:
        raise RunOptionError(f"the {POSTURE} policy balances a rigid body: give --body rigid")
    if hopper.body is not None and options.policy in POLICIES and not options.own_controller:
        raise RunOptionError(
            f"the {options.policy} policy plans on the paper's fixed body; a rigid body runs under --policy "
            f"{POSTURE} or stance_pd_speed_energy, or a controller of one's own (--controller none)"
        )
    try:
        check_body(hopper, ApexState(options.height, options.speed), options.perturbations)
    except ParameterError as error:
        raise RunOptionError(str(error)) from None
    check_placement(options, hopper)
    if not options.own_controller:
        check_controller_parameters(options, hopper)


def check_controller_parameters(options: RunOptions, params: HopperParams) -> None:
    """RunOptionError for what the controller node would refuse at its start (a value out of its range), said
    before anything starts, as the plant's are; the stance controller's policy is its own."""
    try:
        values = controller_overrides(options, params)
    except ParameterError as error:
        raise RunOptionError(f"the controller's model (--mismatch): {error}") from None
    specs = controller_node.SPECS
    if options.policy in STANCE_FEEDBACK_POLICIES:
        specs, values = stance_controller_node.SPECS, {k: v for k, v in values.items() if k != "policy"}
    try:
        parameters.check_values(specs, values)
    except ParameterError as error:
        raise RunOptionError(f"controller parameters: {error}") from None


def check_placement(options: RunOptions, params: HopperParams) -> None:
    """RunOptionError if the leg cannot be placed from the initial apex: at the policy's touchdown angle
    for a fixed-angle policy, at any angle for the others."""
    angle = None
    if options.policy in FIXED_ANGLE_POLICIES:
        angle = DEFAULT_TOUCHDOWN_ANGLE if options.touchdown_angle is None else options.touchdown_angle
    elif options.policy in STANCE_FEEDBACK_POLICIES:  # its angle, else config/controller.yaml's
        angle = options.stance_touchdown_angle
        if angle is None:
            installed = installed_parameters("controller.yaml")
            angle = float(installed.get("stance_touchdown_angle", DEFAULT_STANCE_TOUCHDOWN_ANGLE))
    hip_height = options.height + (0.0 if params.body is None else params.body.hip_y)  # at pitch 0
    try:
        dynamics.check_placement(params, hip_height, angle)
    except ParameterError as error:
        where = "" if params.body is None else f" (the hip's: the height {options.height:g} m plus hip_y)"
        raise RunOptionError(f"{error}{where}") from None
