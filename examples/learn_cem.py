"""Learn a residual on energy regulation over random blocks: the cross-entropy method over a linear policy,
numpy only, on the vector env (tdslip_ros/ApexHop-v0, docs/envs.md).

    python examples/learn_cem.py [--generations 20] [--population 32] [--episodes 8] [--strides 50]
                                 [--sigma 0.04] [--out runs/cem-policy.json]

The setting is the robustness study's operating point (``tdslip robustness``: beta 26 deg, Ebar 3.5, energy
regulation's flat-ground fixed point as the initial apex, ``studies/robustness.py``), on random blocks of
standard deviation ``--sigma`` [m] (0.5 m long, from x = 1 m), the task ``energy`` (hold Ebar 3.5). The action
is a residual on energy regulation's command: a = clip(W f + b, -1, 1), the features f the measured apex's
deviation from the operating point (per 0.1 m, 0.5 m/s; :mod:`tdslip_ros.model.policies.learned`, the
evaluation the ``learned`` policy shares). No ground ahead: the controller node, which runs the saved policy,
senses none.

Each generation draws ``--population`` candidates (W, b) from a diagonal Gaussian, runs each on the same
``--episodes`` grounds (common random numbers: the candidates differ by their parameters only), all lanes in
one vector env, and refits the Gaussian to the best fifth. At the end the learned mean and a zero residual
(energy regulation alone) hop on held-out grounds; the script prints their survival and saves the mean as the
``learned`` policy's file (``tdslip run --policy learned --policy-file FILE``).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tdslip_ros.envs import ApexHopVectorEnv, Task
from tdslip_ros.model import units
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.plant.perturbations import Perturbations
from tdslip_ros.model.plant.terrain import Blocks
from tdslip_ros.model.policies import learned
from tdslip_ros.model.policies.registry import PolicySpec, settings_of
from tdslip_ros.studies.robustness import operating_point

BETA = math.radians(26.0)
EBAR = 3.5
APEX_SCALE = np.array([0.1, 0.5])  # m, m/s: the features' units of apex deviation
ELITE_FRACTION = 0.2
INITIAL_STD, STD_FLOOR = 0.3, 0.02
HELD_OUT_SEED = 1_000_000  # evaluation grounds no generation trains on


def environment(lanes: int, sigma: float, strides: int) -> tuple[ApexHopVectorEnv, np.ndarray]:
    """The vector env at the operating point (no ground ahead observed), and the operating point's apex
    (y [m], xdot [m/s])."""
    energy = units.energy_from_bar(PAPER_PARAMS, EBAR)
    point = operating_point(PAPER_PARAMS, BETA, energy)
    policy = replace(PolicySpec.default("energy"), touchdown_angle=BETA, target_energy=energy)
    env = ApexHopVectorEnv(
        lanes,
        policy=policy,
        task=Task("energy", target=energy),
        perturbations=Perturbations(terrain=Blocks(sigma=sigma, length=0.5, start=1.0)),
        max_strides=strides,
        initial_height=(point.y, point.y),
        initial_speed=(point.xdot, point.xdot),
    )
    return env, np.array([point.y, point.xdot])


def episodes(
    env: ApexHopVectorEnv, apex: np.ndarray, weights: np.ndarray, seeds: list[int]
) -> tuple[np.ndarray, np.ndarray]:
    """One episode per lane, lane i under weights[i] (3 x (features + 1)) on the ground of seeds[i]:
    each lane's return and whether it survived the stride budget."""
    observation, _ = env.reset(seed=seeds)
    returns = np.zeros(env.num_envs)
    running = np.ones(env.num_envs, dtype=bool)
    survived = np.zeros(env.num_envs, dtype=bool)
    while np.any(running):
        f = learned.apex_features(observation[:, 0], observation[:, 1], apex, APEX_SCALE)
        action = learned.linear_action(weights, f)
        observation, reward, terminated, truncated, _ = env.step(action)
        returns += np.where(running, reward, 0.0)
        survived |= running & truncated
        running &= ~(terminated | truncated)
    return returns, survived


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generations", type=int, default=20)
    parser.add_argument("--population", type=int, default=32)
    parser.add_argument("--episodes", type=int, default=8, help="grounds each candidate hops on")
    parser.add_argument("--strides", type=int, default=50, help="the stride budget of an episode")
    parser.add_argument("--sigma", type=float, default=0.04, help="block height standard deviation [m]")
    parser.add_argument("--out", type=Path, default=Path("runs/cem-policy.json"))
    args = parser.parse_args()
    lanes = args.population * args.episodes
    env, apex = environment(lanes, args.sigma, args.strides)
    acted, size = env.config.acted, len(learned.FEATURES) + 1
    mean, std = np.zeros(acted * size), np.full(acted * size, INITIAL_STD)
    elite = max(2, round(ELITE_FRACTION * args.population))
    rng = np.random.default_rng(0)
    started = time.perf_counter()
    for generation in range(args.generations):
        candidates = mean + std * rng.standard_normal((args.population, mean.size))
        weights = np.repeat(candidates.reshape(args.population, acted, size), args.episodes, axis=0)
        seeds = [generation * args.episodes + e for e in range(args.episodes)] * args.population
        returns, survived = episodes(env, apex, weights, seeds)
        score = returns.reshape(args.population, args.episodes).mean(axis=1)
        best = np.argsort(score)[-elite:]
        mean, std = candidates[best].mean(axis=0), np.maximum(candidates[best].std(axis=0), STD_FLOOR)
        print(
            f"generation {generation + 1:3d}: return mean {score.mean():6.2f}, "
            f"elite {score[best].mean():6.2f} (of {args.strides}), survived {survived.mean():5.1%}, "
            f"{time.perf_counter() - started:6.1f} s",
            flush=True,
        )
    held_out = [HELD_OUT_SEED + lane for lane in range(lanes)]
    for name, parameters in (("energy regulation", np.zeros_like(mean)), ("learned residual", mean)):
        weights = np.broadcast_to(parameters.reshape(acted, size), (lanes, acted, size))
        returns, survived = episodes(env, apex, weights, held_out)
        print(
            f"held out, {lanes} grounds: {name:18s} survived {survived.mean():5.1%}, "
            f"return {returns.mean():.2f}"
        )
    config, policy = env.config, env.config.policy
    assert policy is not None  # the env is residual
    residual = learned.LinearResidual(
        weights=mean.reshape(acted, size),
        apex=apex,
        scale=APEX_SCALE,
        base_policy=policy.name,
        # The base's settings but corrections, which the learned policy's spec (a study's, the node's) sets.
        base_settings={
            s.name: getattr(policy, s.name) for s in settings_of(policy.name) if s.name != "corrections"
        },
        half_width=np.asarray(config.residual_half_width),
        command_low=np.asarray(config.command_low),
        command_high=np.asarray(config.command_high),
    )
    learned.save(residual, args.out)
    print(f"saved the learned mean as the learned policy's file {args.out} (final std {std.mean():.3f})")


if __name__ == "__main__":
    main()
