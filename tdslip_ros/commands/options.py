"""The ``tdslip`` vocabulary, declared once: the options several subcommands share, each with one name, one
unit and one default, and the help formatter every subcommand uses.

Values on the command line are SI, or carry their unit in the option's name where the natural value is not
(``--touchdown-angle-deg``, the dimensionless ``--energy-bar`` and ``--speeds-bar``). Old spellings keep
working for now, hidden from ``--help``, with a one-line deprecation warning on stderr.
"""

from __future__ import annotations

import argparse
import difflib
import math
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, NoReturn

from tdslip_ros.interfaces import BODY_KINDS, FIXED_BODY, HOPPER_PARAMETERS, read_hopper_file
from tdslip_ros.model.analytic.apex_map import ANALYTIC_MAPS, DEFAULT_ANALYTIC_MAP, SpeedSource
from tdslip_ros.model.paper import UPRIGHT_TRUNK
from tdslip_ros.model.params import HopperParams, ParameterError, RigidBody
from tdslip_ros.model.policies.registry import (
    DEFAULT_APEX_HEIGHT,
    DEFAULT_APEX_SPEED,
    DEFAULT_TOUCHDOWN_ANGLE,
)

TOUCHDOWN_ANGLE_DEG = round(math.degrees(DEFAULT_TOUCHDOWN_ANGLE), 9)
"""The model's touchdown angle [deg] (20): the default of ``--touchdown-angle-deg`` everywhere."""


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions as written (line breaks kept); every option's help ends with its default, unless the
    help already states it: "(default: X)", "(default: off)" for a flag, "(required)" for a required one."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if not action.option_strings or "default" in text or action.default is argparse.SUPPRESS:
            return text
        if action.required:
            return f"{text} (required)"
        if isinstance(action, argparse._StoreTrueAction):
            return f"{text} (default: off)"
        if action.default is None:
            return text  # the help says in words what no value means
        return f"{text} (default: {shown(action.default)})".replace("%", "%%")


def shown(value: Any) -> str:
    """A default as the user would type it."""
    if isinstance(value, list | tuple):
        return " ".join(shown(item) for item in value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


class CommandParser(argparse.ArgumentParser):
    """A subcommand's parser: an option it does not know is refused before anything else is checked (a
    missing required option would hide it), in one line that names the closest option it has."""

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        given = list(sys.argv[1:] if args is None else args)
        for word in given[: given.index("--")] if "--" in given else given:
            if (suggestion := self._unknown_option(word)) is not None:
                self.error(suggestion)
        return super().parse_known_args(given, namespace)

    def _unknown_option(self, word: str) -> str | None:
        """Why ``word`` is an option this parser does not have, with the closest it has; None where it is
        one (or an abbreviation argparse resolves), a value, or has no close match (argparse says so)."""
        if not word.startswith("-") or word == "-" or _is_number(word):
            return None
        spelling = word.split("=", 1)[0]
        known = [option for action in self._actions for option in action.option_strings]
        if spelling in known or (len(word) > 2 and word[:2] in known and not word.startswith("--")):
            return None
        if self.allow_abbrev and spelling.startswith("--"):
            if any(option.startswith(spelling) for option in known):
                return None  # an abbreviation: argparse takes it, or says it is ambiguous
        visible = [
            option
            for action in self._actions
            if action.help is not argparse.SUPPRESS
            for option in action.option_strings
            if option.startswith("--")
        ]
        closest = difflib.get_close_matches(spelling, visible, n=1)
        return f"unrecognized option {spelling}; did you mean {closest[0]}?" if closest else None

    def error(self, message: str) -> NoReturn:
        """One line on stderr and exit status 2, pointing at --help rather than printing the usage."""
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def command_parser(name: str, description: str) -> argparse.ArgumentParser:
    """The parser of ``tdslip NAME``, with the shared help formatter and :class:`CommandParser`'s errors."""
    return CommandParser(prog=f"tdslip {name}", description=description, formatter_class=HelpFormatter)


class _Deprecated(argparse.Action):
    """An old spelling of an option: stores into the new one's destination and warns in one line."""

    def __init__(self, option_strings: Sequence[str], dest: str, use: str = "", **kwargs: Any) -> None:
        super().__init__(option_strings, dest, **kwargs)
        self.use = use

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        print(f"{parser.prog}: {option_string} is deprecated; use {self.use}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def deprecated(parser: argparse.ArgumentParser | Any, new: argparse.Action, *old: str) -> None:
    """Accept the old spellings ``old`` of the option ``new`` (same unit), hidden from --help."""
    for spelling in old:
        parser.add_argument(
            spelling,
            action=_Deprecated,
            dest=new.dest,
            use=new.option_strings[0],
            type=new.type,
            nargs=new.nargs,
            choices=new.choices,
            metavar=new.metavar,
            default=argparse.SUPPRESS,
            help=argparse.SUPPRESS,
        )


def add_touchdown_angle(
    parser: argparse.ArgumentParser | Any,
    *old: str,
    what: str = "",
    unset: str | None = None,
    default: float = TOUCHDOWN_ANGLE_DEG,
) -> argparse.Action:
    """``--touchdown-angle-deg`` [deg], default the model's 20 deg (a command whose figure needs another says
    why in ``what``), or (with ``unset``) None, described in words by ``unset``; ``old``: its deprecated
    spellings in this command."""
    action = parser.add_argument(
        "--touchdown-angle-deg",
        type=float,
        default=None if unset else default,
        metavar="DEG",
        help=f"touchdown angle beta [deg]{what}" + (f" (default: {unset})" if unset else ""),
    )
    deprecated(parser, action, *old)
    return action


def touchdown_angle_error(degrees: float) -> str | None:
    """Why ``--touchdown-angle-deg`` cannot be ``degrees``, or None."""
    if 0.0 < degrees < 90.0:
        return None
    return f"--touchdown-angle-deg must be in (0, 90) deg, got {degrees:g}"


def check_strides_and_angle(strides: int, degrees: float) -> None:
    """ParameterError for a stride count below 1 or a touchdown angle outside (0, 90) deg."""
    if strides < 1:
        raise ParameterError(f"--strides must be at least 1, got {strides}")
    reason = touchdown_angle_error(degrees)
    if reason is not None:
        raise ParameterError(reason)


def add_initial_apex(parser: argparse.ArgumentParser | Any) -> None:
    """``--height`` [m] and ``--speed`` [m/s] of the initial apex, defaults the model's (1 m, 5 m/s)."""
    parser.add_argument(
        "--height", type=float, default=DEFAULT_APEX_HEIGHT, metavar="M", help="initial apex height [m]"
    )
    parser.add_argument(
        "--speed", type=float, default=DEFAULT_APEX_SPEED, metavar="M_PER_S", help="initial apex speed [m/s]"
    )


def add_energy_bar(parser: argparse.ArgumentParser | Any, default: float, what: str, *old: str) -> None:
    """``--energy-bar``: an apex energy, dimensionless E/(m g r0)."""
    action = parser.add_argument(
        "--energy-bar",
        type=float,
        default=default,
        metavar="EBAR",
        help=f"{what}, E/(m g r0) (dimensionless)",
    )
    deprecated(parser, action, *old)


def add_analytic_map(parser: argparse.ArgumentParser | Any, what: str = "", unset: str | None = None) -> None:
    """``--map ours|paper`` (model.analytic.ANALYTIC_MAPS: the analytic map's next apex speed from the energy
    balance, or from the liftoff velocity of eq. 7 as printed), default ours, or (with ``unset``) None,
    described in words by ``unset``; read it with :func:`analytic_map_speed`."""
    default = None if unset else DEFAULT_ANALYTIC_MAP
    parser.add_argument(
        "--map",
        choices=list(ANALYTIC_MAPS),
        default=default,
        help="the analytic map: ours (next apex speed from the energy balance) or paper (from eq. 7's "
        f"liftoff velocity, as printed){what} (default: {unset or default})",
    )


def add_policy_file(parser: argparse.ArgumentParser | Any) -> None:
    """``--policy-file FILE``, the learned policy's file (model.learned); read it with :func:`policy_file`."""
    parser.add_argument(
        "--policy-file",
        type=Path,
        help="the learned policy's file, examples/learn_cem.py writes one (default: none; needed by learned)",
    )


def policy_file(args: argparse.Namespace) -> str | None:
    """The learned policy's file, absolute (the nodes and the study's workers run elsewhere), or None."""
    return None if args.policy_file is None else str(args.policy_file.resolve())


def analytic_map_speed(args: argparse.Namespace) -> SpeedSource:
    return ANALYTIC_MAPS[args.map]


HOPPER_OPTIONS = {
    "m": ("--mass", "KG", "body mass m [kg]"),
    "k": ("--stiffness", "N_PER_M", "leg stiffness k [N/m]"),
    "c": ("--damping", "N_S_PER_M", "leg damping c [N s/m]"),
    "r0": ("--rest-length", "M", "leg rest length r0 [m]"),
}
"""The hopper's SI options by HopperParams field (gravity stays the model's); with --kbar, --zeta0 and
--hopper FILE, declared here once for every command that takes a hopper (:func:`add_hopper`)."""


def add_hopper(parser: argparse.ArgumentParser | Any, default: str, *old_rest_length: str) -> None:
    """The hopper options (one group): ``--hopper FILE`` (a hopper file, ``tdslip identify`` writes one),
    then each of ``--mass``, ``--stiffness``, ``--damping``, ``--rest-length`` [SI] or the paper's ``--kbar``
    and ``--zeta0`` (eq. 24) replacing the file's or the default's value; ``default`` says in words what the
    hopper is without them. Read them with :func:`hopper_of`."""
    group = parser.add_argument_group(f"the hopper (default: {default}; an option replaces its value)")
    group.add_argument(
        "--hopper", type=Path, metavar="FILE", help="hopper file (YAML, SI; tdslip identify) (default: none)"
    )
    for option, metavar, what in HOPPER_OPTIONS.values():
        action = group.add_argument(
            option, type=float, metavar=metavar, help=f"{what} (default: the hopper's)"
        )
        if option == "--rest-length":
            deprecated(group, action, *old_rest_length)
    for option, what, instead in (("--kbar", "leg stiffness k r0/(m g)", "--stiffness"),
                                  ("--zeta0", "leg damping ratio c/(2 sqrt(m k))", "--damping")):  # fmt: skip
        group.add_argument(
            option, type=float, help=f"{what}, dimensionless; or {instead} (default: the hopper's)"
        )


def hopper_given(args: argparse.Namespace) -> bool:
    """Whether any of :func:`add_hopper`'s options was given."""
    options = [
        "hopper",
        "kbar",
        "zeta0",
        *(option[2:].replace("-", "_") for option, _, _ in HOPPER_OPTIONS.values()),
    ]
    return any(getattr(args, name) is not None for name in options)


def hopper_of(args: argparse.Namespace, default: HopperParams) -> HopperParams:
    """The hopper of :func:`add_hopper`'s options: the file's, else ``default``, with the given values
    replaced (kbar and zeta0 with the resulting m and r0). ParameterError, one line, for a bad value, a file
    that cannot serve, or a value given twice (--stiffness with --kbar, --damping with --zeta0)."""
    given = {
        field: getattr(args, option[2:].replace("-", "_")) for field, (option, _, _) in HOPPER_OPTIONS.items()
    }
    for field, bar in (("k", "kbar"), ("c", "zeta0")):
        if given[field] is not None and getattr(args, bar) is not None:
            raise ParameterError(f"give {HOPPER_OPTIONS[field][0]} or --{bar}, not both")
    base = default if args.hopper is None else read_hopper_file(args.hopper)
    values = {field: getattr(base, field) for field in HOPPER_PARAMETERS}
    values |= {field: value for field, value in given.items() if value is not None}
    m, r0, g = values["m"], values["r0"], values["g"]
    if args.kbar is not None:
        values["k"] = HopperParams.from_dimensionless(args.kbar, 0.0, m=m, r0=r0, g=g).k
    if args.zeta0 is not None:
        values["c"] = HopperParams.from_dimensionless(
            values["k"] * r0 / (m * g), args.zeta0, m=m, r0=r0, g=g
        ).c
    return HopperParams(**values)


def add_body(parser: argparse.ArgumentParser) -> None:
    """The body options (one group): ``--body fixed|rigid`` and a rigid body's ``--body-inertia``,
    ``--hip X Y`` and ``--tip-limit`` [SI], by default the upright trunk's (model/paper.py). Read them with
    :func:`body_of`."""
    trunk = UPRIGHT_TRUNK
    group = parser.add_argument_group(
        "the body (docs/rotating_body.md; default: the paper's, fixed level; rigid: the upright trunk, "
        f"J {trunk.inertia:g} kg m^2, hip {-trunk.hip_y:g} m below the centre of mass)"
    )
    group.add_argument(
        "--body", choices=BODY_KINDS, default=FIXED_BODY, help="fixed or freely rotating in pitch"
    )
    group.add_argument(
        "--body-inertia",
        type=float,
        metavar="J",
        help=f"rigid: pitch inertia [kg m^2] (default: {trunk.inertia:g})",
    )
    group.add_argument(
        "--hip",
        type=float,
        nargs=2,
        metavar=("X", "Y"),
        help=f"rigid: the hip from the centre of mass at pitch 0 [m] (default: {trunk.hip_x:g} "
        f"{trunk.hip_y:g})",
    )
    group.add_argument(
        "--tip-limit",
        type=float,
        metavar="RAD",
        help=f"rigid: |pitch| past which it has tipped [rad] (default: {trunk.tip_limit:.4g})",
    )


def body_given(args: argparse.Namespace) -> bool:
    """Whether a rigid body, or any of its options, was given (:func:`add_body`)."""
    return args.body != FIXED_BODY or any(
        getattr(args, name) is not None for name in ("body_inertia", "hip", "tip_limit")
    )


def body_of(args: argparse.Namespace, hopper: HopperParams) -> HopperParams:
    """``hopper`` with :func:`add_body`'s body; ParameterError, one line, for a rigid body's option given
    without ``--body rigid`` or a bad value."""
    given = [name for name in ("body_inertia", "hip", "tip_limit") if getattr(args, name) is not None]
    if args.body == FIXED_BODY:
        if given:
            raise ParameterError(f"--{given[0].replace('_', '-')} needs --body rigid")
        return replace(hopper, body=None)
    hip_x, hip_y = (UPRIGHT_TRUNK.hip_x, UPRIGHT_TRUNK.hip_y) if args.hip is None else args.hip
    inertia = UPRIGHT_TRUNK.inertia if args.body_inertia is None else args.body_inertia
    tip_limit = UPRIGHT_TRUNK.tip_limit if args.tip_limit is None else args.tip_limit
    return replace(hopper, body=RigidBody(inertia, hip_x, hip_y, tip_limit))
