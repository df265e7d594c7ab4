"""Throughput of the apex-hop vector env beside SyncVectorEnv of the single env and the batched engine.

    taskset -c 0 python bench/bench_envs.py [--lanes 256] [--steps 40] [--sync-steps 4] [--rounds 3]
                                             [--blocks 0.04]

The same work three ways, on one core (run it under ``taskset -c 0``; numba and BLAS are held to one
thread here): energy regulation (the node suite's default setting, beta 20 deg) hopping from the env's
initial apexes, with a zero residual action, on flat ground or, with ``--blocks SIGMA`` [m], on random
blocks with every lane on its own ground:

1. ``ApexHopVectorEnv``: all lanes in one engine call per step;
2. ``gymnasium.vector.SyncVectorEnv`` of ``ApexHopEnv``: one engine call per lane and step (``--sync-steps``
   steps, as it is slow);
3. the batched engine called directly (:func:`~tdslip_ros.model.plant.batch.simulate_strides` with the
policy), no
   environment around it.

Rates are per second of the process's CPU time (one thread: what the core spent on it, whatever else shares
the machine), the best of ``--rounds`` interleaved rounds, ratios to the vector env. Two rates: env steps, and
strides (an env's step that starts the next episode takes none; the engine's lanes stop at their failures, so
it hops fewer lanes per call as they fail). The machine's load average is printed beside them.
"""

from __future__ import annotations

import os

for _variable in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import argparse  # noqa: E402  (the thread counts must be set before numpy and numba load)
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import replace  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

from tdslip_ros.envs import ApexHopEnv, ApexHopVectorEnv  # noqa: E402
from tdslip_ros.envs.lanes import terrain_seed  # noqa: E402
from tdslip_ros.model.paper import PAPER_PARAMS  # noqa: E402
from tdslip_ros.model.plant.batch import simulate_strides  # noqa: E402
from tdslip_ros.model.plant.perturbations import Perturbations  # noqa: E402
from tdslip_ros.model.plant.terrain import Blocks  # noqa: E402
from tdslip_ros.model.policies.registry import PolicySpec  # noqa: E402
from tdslip_ros.model.stability.basins import EXACT_TOLERANCE  # noqa: E402

POLICY = PolicySpec.default("energy")
SEED = 0


Run = Callable[[], tuple[int, int]]
"""A timed run: it returns the env steps and the strides it took."""


def rates(run: Run) -> np.ndarray:
    """Env steps and strides per second of ``run``'s CPU time (one thread: the time of the core it ran on)."""
    start = time.process_time()
    counts = run()
    return np.array(counts) / (time.process_time() - start)


def vector_steps(env: gym.vector.VectorEnv, steps: int) -> Run:
    """``steps`` steps of every lane; a lane's step after its episode ended resets it and takes no stride."""

    def run() -> tuple[int, int]:
        env.reset(seed=SEED)
        action = np.zeros(env.action_space.shape)
        resetting = np.zeros(env.num_envs, dtype=bool)
        strides = 0
        for _ in range(steps):
            strides += int(np.sum(~resetting))
            _, _, terminated, truncated, _ = env.step(action)
            resetting = terminated | truncated
        return steps * env.num_envs, strides

    return run


def engine_strides(settings: dict, lanes: int, steps: int) -> Run:
    """The batched engine with the env's initial apexes (lane i: the single env reset with SEED + i)."""
    initial = [ApexHopEnv(**settings).reset(seed=SEED + lane)[0][:2] for lane in range(lanes)]
    y0, xdot0 = np.array(initial).T
    perturbations = settings.get("perturbations")
    if perturbations is not None:  # each lane on the ground of its first episode, as in the env
        seeds = np.array([terrain_seed(SEED + lane, 0) for lane in range(lanes)])
        perturbations = replace(perturbations, terrain=replace(perturbations.terrain, seed=seeds))

    def policy(stride: int, y: np.ndarray, xdot: np.ndarray) -> tuple[np.ndarray, ...]:
        return tuple(POLICY.commands(PAPER_PARAMS, y, xdot, xdot))

    def run() -> tuple[int, int]:
        result = simulate_strides(
            PAPER_PARAMS,
            y0,
            xdot0,
            policy,
            steps,
            rtol=EXACT_TOLERANCE,
            atol=EXACT_TOLERANCE,
            perturbations=perturbations,
        )
        failed = result.failure_stride >= 0
        strides = int(np.sum(np.where(failed, result.failure_stride + 1, steps)))
        return strides, strides  # a lane stops at its failure: its strides are its steps

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=256, help="lanes of each vectorised run")
    parser.add_argument("--steps", type=int, default=40, help="steps of the vector env and the engine")
    parser.add_argument("--sync-steps", type=int, default=4, help="steps of SyncVectorEnv (slow)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of the three; the best rate of each")
    parser.add_argument("--blocks", type=float, default=0.0, help="random blocks of this sigma [m] (0: flat)")
    args = parser.parse_args()
    settings: dict = {"policy": POLICY, "task": "energy", "max_strides": 10_000}
    if args.blocks > 0.0:
        settings["perturbations"] = Perturbations(terrain=Blocks(sigma=args.blocks, length=0.5))
    vector = ApexHopVectorEnv(args.lanes, **settings)
    sync = gym.vector.SyncVectorEnv([lambda: ApexHopEnv(**settings)] * args.lanes)
    warm = ApexHopVectorEnv(2, **settings)  # compiles and caches the kernels before any timing
    vector_steps(warm, 2)()
    runs = {
        "ApexHopVectorEnv": vector_steps(vector, args.steps),
        "SyncVectorEnv(ApexHopEnv)": vector_steps(sync, args.sync_steps),
        "batched engine (simulate_strides)": engine_strides(settings, args.lanes, args.steps),
    }
    ground = f"blocks sigma {args.blocks:g} m" if args.blocks > 0.0 else "flat ground"
    print(f"{args.lanes} lanes, energy regulation, zero residual, {ground}")
    print(f"load average before: {os.getloadavg()}")
    best = {name: np.zeros(2) for name in runs}
    for _ in range(args.rounds):  # interleaved, the best of each: the least disturbed by other processes
        for name, run in runs.items():
            best[name] = np.maximum(best[name], rates(run))
    reference = best["ApexHopVectorEnv"]
    header = ("env steps/s", "ratio", "strides/s", "ratio")
    print(
        f"{'per second of CPU time:':36s} {header[0]:>12s} {header[1]:>7s} {header[2]:>12s} {header[3]:>7s}"
    )
    for name, (steps, strides) in best.items():
        step_ratio, stride_ratio = steps / reference[0], strides / reference[1]
        print(f"{name:36s} {steps:12.0f} {step_ratio:7.3f} {strides:12.0f} {stride_ratio:7.3f}")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
