"""The state of some apex-hop episodes side by side, and their strides in one call of the batched engine.

The single environment is one lane of :class:`HopperLanes`, the vector environment many: both run the same
code, so a lane of the vector environment hops exactly as a single environment with the same seed.

**Seeding.** A lane's episodes are numbered from its last seeded reset: ``reset(seed=s)`` starts episode 0 of
stream seed s, each reset without a seed the next episode (a lane never seeded draws its stream seed from its
generator at its first reset). Episode e of stream seed s takes the model's random streams
(:mod:`tdslip_ros.model.plant.perturbations`) of seed s, trajectory e, stride k for sensing, placement and
pushes, and random blocks of seed :func:`terrain_seed` (s, e); the initial apex is drawn from the lane's
generator (Gymnasium's ``np_random``). An episode is therefore a function of (seed, episode, actions) only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from tdslip_ros.envs.config import COMMAND_FIELDS, LIFTOFF_RULE, HopConfig
from tdslip_ros.model.dynamics import FloatArray
from tdslip_ros.model.events import FAILURE_KINDS, NO_FAILURE_CODE
from tdslip_ros.model.params import HopperParams, ParameterError
from tdslip_ros.model.plant.batch import batch_apex_return_map
from tdslip_ros.model.plant.perturbations import DRAW_BLOCK, Perturbations, StrideConditions
from tdslip_ros.model.plant.terrain import Blocks, IntArray, Terrain
from tdslip_ros.model.policies.controllers import ramp_to_liftoff
from tdslip_ros.model.policies.learned import residual_command

SEED_BOUND = 2**31
"""Stream seeds drawn for unseeded lanes, and terrain seeds, lie below this (the model's terrain seeds do)."""
SEED_LIMIT = 2**63
"""A reset's seed lies below this: a lane keeps its stream seed as a 64-bit integer."""
FAILURE_TEXTS = np.array(["", *(kind.value for kind in FAILURE_KINDS)], dtype=object)
"""info ``failure`` by failure code + 1: "" for none, else the kind's name."""


def check_seeds(seeds: Sequence[int | None]) -> None:
    """ValueError unless each seed is None or an integer in [0, SEED_LIMIT)."""
    for seed in seeds:
        if seed is not None and not (isinstance(seed, int | np.integer) and 0 <= seed < SEED_LIMIT):
            raise ValueError(f"a seed must be an integer in [0, 2**63), got {seed!r}")


def terrain_seed(stream_seed: int, episode: int) -> int:
    """The random blocks' seed of episode ``episode`` of ``stream_seed`` (below SEED_BOUND)."""
    state = np.random.SeedSequence(stream_seed, spawn_key=(episode,)).generate_state(1)
    return int(state[0]) >> 1


def episode_perturbations(template: Perturbations, stream_seed: int, episode: int) -> Perturbations:
    """``template`` with the episode's seeds (module docstring); its draws are trajectory ``episode``'s."""
    terrain = template.terrain
    if isinstance(terrain, Blocks):
        terrain = replace(terrain, seed=terrain_seed(stream_seed, episode))
    return replace(
        template,
        terrain=terrain,
        sensing=replace(template.sensing, seed=stream_seed),
        placement=replace(template.placement, seed=stream_seed),
        pushes=replace(template.pushes, seed=stream_seed),
    )


@dataclass(frozen=True)
class StrideOutcomes:
    """The outcome of one stride of some lanes: observation rows, reward, terminated, truncated, and the
    info arrays (:mod:`.apex_hop` lists them)."""

    observation: FloatArray
    reward: FloatArray
    terminated: npt.NDArray[np.bool_]
    truncated: npt.NDArray[np.bool_]
    info: dict[str, Any]


class HopperLanes:
    """``count`` episodes of one :class:`~tdslip_ros.envs.config.HopConfig` (module docstring)."""

    def __init__(self, config: HopConfig, count: int) -> None:
        self.config = config
        self.count = count
        template = config.perturbations
        self._drawn = template.random or template.pushes.active
        controller = template.mismatch.controller_params(config.params)
        if not isinstance(controller, HopperParams):
            raise ParameterError("the environments take one mismatch for all lanes (scalar factors)")
        self._controller = controller
        low, high = np.asarray(config.command_low), np.asarray(config.command_high)
        self._low, self._high = low[:, None], high[:, None]
        self._middle = (low + high) / 2.0
        self._direct_half_width = ((high - low) / 2.0)[:, None]
        self._residual_half_width = np.asarray(config.residual_half_width)[:, None]
        self._observation_low, self._observation_high = config.observation_bounds()
        self.y, self.xdot, self.x, self.ground = (np.zeros(count) for _ in range(4))
        self.measured = np.zeros((2, count))
        self.stride = np.zeros(count, dtype=np.int64)
        self.stream_seed = np.full(count, -1, dtype=np.int64)
        self.episode = np.zeros(count, dtype=np.int64)
        self.terrain_seed = np.zeros(count, dtype=np.int64)
        self.policy_command = np.zeros((3, count))
        """The residual's centre: the policy's last command per lane (rad, N m, s)."""
        self.previous_speed = np.zeros(count)
        self.last_inputs: dict[str, FloatArray] = {}
        """The inputs of the last stride of the lanes stepped (apex y, xdot, x, ground; command; angle
        error, push), for drawing it."""
        self._draw_rows = np.zeros((4, DRAW_BLOCK, count))
        self._draw_block = np.full(count, -1, dtype=np.int64)

    # --- episodes ------------------------------------------------------------------------------

    def reset(
        self, lanes: npt.ArrayLike, seeds: Sequence[int | None], generators: Sequence[np.random.Generator]
    ) -> FloatArray:
        """Start the next episode of each lane (a new stream where its seed is given); observation rows."""
        index = np.asarray(lanes, dtype=np.int64)
        check_seeds(seeds)
        for lane, seed, generator in zip(index.tolist(), seeds, generators, strict=True):
            if seed is not None:
                self.stream_seed[lane], self.episode[lane] = seed, 0
            elif self.stream_seed[lane] < 0:
                self.stream_seed[lane], self.episode[lane] = int(generator.integers(SEED_BOUND)), 0
            else:
                self.episode[lane] += 1
            self.terrain_seed[lane] = terrain_seed(int(self.stream_seed[lane]), int(self.episode[lane]))
            self.y[lane] = generator.uniform(*self.config.initial_height)
            self.xdot[lane] = generator.uniform(*self.config.initial_speed)
        self.x[index] = 0.0
        self.ground[index] = self.terrain(index).height(self.x[index])
        self.stride[index] = 0
        self.policy_command[:, index] = self._middle[:, None]
        self._draw_block[index] = -1
        self._measure(index)
        self.previous_speed[index] = self.measured[1, index]
        return self.observe(index)

    def terrain(self, lanes: IntArray) -> Terrain:
        """The ground of the lanes' current episodes (per-lane seeds for random blocks)."""
        terrain = self.config.perturbations.terrain
        return replace(terrain, seed=self.terrain_seed[lanes]) if isinstance(terrain, Blocks) else terrain

    def perturbations(self, lane: int) -> Perturbations:
        """The perturbations of the lane's current episode, its seeds set."""
        return episode_perturbations(
            self.config.perturbations, int(self.stream_seed[lane]), int(self.episode[lane])
        )

    def _draws(self, lanes: IntArray, strides: IntArray) -> FloatArray:
        """(4, lanes): the height and speed errors [m, m/s], angle error [rad] and push [m/s] of the lanes at
        the given strides; each lane's rows are drawn a block of DRAW_BLOCK strides at a time."""
        if not self._drawn:
            return np.zeros((4, lanes.size))
        blocks = strides // DRAW_BLOCK
        for lane, block in zip(lanes.tolist(), blocks.tolist(), strict=True):
            if self._draw_block[lane] != block:
                draws = self.perturbations(lane).draws([self.episode[lane]], block * DRAW_BLOCK, DRAW_BLOCK)
                self._draw_rows[:, :, lane] = np.stack(
                    [
                        draws.height_error[:, 0],
                        draws.speed_error[:, 0],
                        draws.angle_error[:, 0],
                        draws.push[:, 0],
                    ]
                )
                self._draw_block[lane] = block
        return self._draw_rows[:, strides % DRAW_BLOCK, lanes]

    def _measure(self, lanes: IntArray) -> None:
        """The sensor's reading of the lanes' current apexes (noise of their current strides)."""
        errors = self._draws(lanes, self.stride[lanes])
        self.measured[0, lanes] = self.y[lanes] + errors[0]
        self.measured[1, lanes] = self.xdot[lanes] + errors[1]

    def observe(self, lanes: IntArray) -> FloatArray:
        """Observation rows of the lanes (:mod:`.config`)."""
        columns = [self.measured[0, lanes], self.measured[1, lanes]]
        if self.config.task.has_target:
            columns.append(np.full(lanes.size, self.config.task.target))
        if self.config.lookahead:
            terrain = self.terrain(lanes)
            columns += [terrain.height(self.x[lanes] + d) - self.ground[lanes] for d in self.config.lookahead]
        rows: FloatArray = np.clip(np.stack(columns, axis=1), self._observation_low, self._observation_high)
        return rows

    # --- strides -------------------------------------------------------------------------------

    def command(self, lanes: IntArray, action: FloatArray) -> FloatArray:
        """(3, lanes): the stance commands the actions (lanes, acted) give (:mod:`.config`)."""
        config = self.config
        acted = np.zeros((3, lanes.size))
        acted[: config.acted] = np.clip(np.asarray(action, dtype=np.float64).T, -1.0, 1.0)  # the action box
        if config.policy is None:
            centre, half_width = np.broadcast_to(self._middle[:, None], acted.shape), self._direct_half_width
        else:
            planned = config.policy.commands(
                self._controller, self.measured[0, lanes], self.measured[1, lanes], self.previous_speed[lanes]
            )
            planned_rows = np.stack(
                [np.broadcast_to(np.asarray(f, dtype=np.float64), lanes.shape) for f in planned]
            )
            answered = np.all(np.isfinite(planned_rows), axis=0)
            self.policy_command[:, lanes[answered]] = planned_rows[:, answered]
            centre, half_width = self.policy_command[:, lanes], self._residual_half_width
        command: FloatArray = residual_command(centre, half_width, acted, self._low, self._high)
        if config.ramp_duration == LIFTOFF_RULE:
            liftoff = ramp_to_liftoff(
                self._controller, self.measured[0, lanes], self.measured[1, lanes], command[0], command[1]
            ).t_f
            ramp = np.where(np.isfinite(liftoff), liftoff, self._middle[2])
            command[2] = np.clip(ramp, self._low[2], self._high[2])
        elif config.ramp_duration is not None:
            command[2] = config.ramp_duration
        return command

    def step(self, lanes: npt.ArrayLike, action: npt.ArrayLike) -> StrideOutcomes:
        """One stride of each of ``lanes`` under ``action`` (lanes, acted): one call of the batched engine."""
        index = np.asarray(lanes, dtype=np.int64)
        config = self.config
        actions = np.asarray(action, dtype=np.float64)
        # Checked before any lane's state changes: a refused step leaves the lanes as they were.
        if actions.shape != (index.size, config.acted):
            raise ValueError(f"actions must have the shape {(index.size, config.acted)}, got {actions.shape}")
        if not np.all(np.isfinite(actions)):
            raise ValueError("actions must be finite")
        command = self.command(index, actions)
        self.previous_speed[index] = self.measured[1, index]
        errors = self._draws(index, self.stride[index])
        self.last_inputs = {
            "y": self.y[index],
            "xdot": self.xdot[index],
            "x": self.x[index],
            "ground": self.ground[index],
            **dict(zip(COMMAND_FIELDS, command, strict=True)),
            "angle_error": errors[2],
            "push": errors[3],
        }
        result = batch_apex_return_map(
            config.params,
            self.y[index],
            self.xdot[index],
            *command,
            rtol=config.tolerance,
            atol=config.tolerance,
            conditions=StrideConditions(
                x=self.x[index],
                ground=self.ground[index],
                terrain=self.terrain(index),
                tau_max=config.perturbations.tau_max,
                push=errors[3],
                angle_error=errors[2],
            ),
        )
        failed = result.failure != NO_FAILURE_CODE
        survived = index[~failed]
        self.y[survived], self.xdot[survived] = result.y[~failed], result.xdot[~failed]
        self.x[survived], self.ground[survived] = result.x[~failed], result.ground[~failed]
        self.stride[index] += 1
        self._measure(survived)
        info = {
            "failure": FAILURE_TEXTS[result.failure + 1],
            "hip_work": result.hip_work,
            "damping_loss": result.damping_loss,
            "spring_loss": result.spring_loss,
            **dict(zip(COMMAND_FIELDS, command, strict=True)),
            "apex_height": result.y,
            "apex_speed": result.xdot,
            "x": result.x,
            "ground": result.ground,
            "push": errors[3],
            "saturated": result.saturated,
        }
        return StrideOutcomes(
            observation=self.observe(index),
            reward=config.task.reward(config.params, result.y, result.xdot, failed),
            terminated=failed,
            truncated=~failed & (self.stride[index] >= config.max_strides),
            info=info,
        )
