"""The learning environments (tdslip_ros.envs): Gymnasium's checks, reproducible episodes, the vector env
lane by lane against the single env, named failures, and the rewards against the exact map."""

from __future__ import annotations

import importlib.util
import math
import sys
import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from types import ModuleType

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from support.learned_policy import learned_file, malformed_file

from tdslip_ros.envs import ENV_ID, ApexHopEnv, ApexHopVectorEnv, Task
from tdslip_ros.envs.lanes import terrain_seed
from tdslip_ros.model.paper import PAPER_PARAMS
from tdslip_ros.model.params import ApexState, ParameterError, StanceCommand
from tdslip_ros.model.plant.exact_map import apex_return_map
from tdslip_ros.model.plant.perturbations import Perturbations, PlacementNoise, Pushes, SensingNoise
from tdslip_ros.model.plant.terrain import Blocks
from tdslip_ros.model.policies import learned
from tdslip_ros.model.policies.controllers import ramp_to_liftoff
from tdslip_ros.model.policies.registry import LEARNED, PolicyError, PolicySpec, check_policy_file

PERTURBED = Perturbations(
    terrain=Blocks(sigma=0.04, length=0.5, start=1.0),
    sensing=SensingNoise(height=0.01, speed=0.05),
    placement=PlacementNoise(sigma=math.radians(0.5)),
    tau_max=400.0,
    pushes=Pushes(size=0.2, rate=0.2),
)
RESIDUAL = {"policy": PolicySpec.default("energy"), "task": "energy"}
REPO = Path(__file__).parents[1]


def episode(env: gym.Env, seed: int, actions: np.ndarray) -> list[tuple]:
    """(observation, reward, terminated, truncated, info) of each step until the episode ends."""
    observation, _ = env.reset(seed=seed)
    steps = [(observation, 0.0, False, False, {})]
    for action in actions:
        steps.append(env.step(action))
        if steps[-1][2] or steps[-1][3]:
            break
    return steps


@pytest.mark.parametrize(
    "settings",
    [{}, {"perturbations": PERTURBED, "lookahead": (0.5, 1.0)}, {**RESIDUAL, "perturbations": PERTURBED}],
    ids=["plain", "perturbed", "residual"],
)
def test_check_env_passes_without_warnings(settings: dict) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(ENV_ID, render_mode="rgb_array", **settings)
        check_env(env.unwrapped)
        env.reset(seed=0)
        env.step(env.action_space.sample())
        frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3


def test_same_seed_same_episode_and_another_seed_another() -> None:
    env = ApexHopEnv(perturbations=PERTURBED, **RESIDUAL)
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, (20, 3))
    first, again, other = (episode(env, seed, actions) for seed in (7, 7, 8))
    np.testing.assert_equal(first, again)  # NaN equal to NaN (the flows of a failed stride)
    assert not np.array_equal(first[1][0], other[1][0])


def test_vector_env_is_the_single_env_lane_by_lane() -> None:
    """Residual (the policy plans on all lanes at once) and every perturbation, through autoresets."""
    settings = {**RESIDUAL, "perturbations": PERTURBED}
    lanes, steps = 64, 7
    vector = ApexHopVectorEnv(lanes, max_strides=5, **settings)
    single = gym.vector.SyncVectorEnv([lambda: ApexHopEnv(max_strides=5, **settings)] * lanes)
    actions = np.random.default_rng(3).uniform(-1.0, 1.0, (steps, lanes, 3))
    ours, theirs = vector.reset(seed=11), single.reset(seed=11)
    np.testing.assert_array_equal(ours[0], theirs[0])
    ended = 0
    for action in actions:
        ours, theirs = vector.step(action), single.step(action)
        for mine, reference in zip(ours[:4], theirs[:4], strict=True):
            np.testing.assert_array_equal(mine, reference)
        assert ours[4].keys() == theirs[4].keys()
        for key in ours[4]:
            np.testing.assert_array_equal(ours[4][key], theirs[4][key], err_msg=key)
        ended += int(np.sum(ours[2] | ours[3]))
    assert ended > lanes // 2  # autoresets were exercised


def test_a_failure_terminates_with_its_kind_in_info() -> None:
    env = ApexHopEnv(task="survive")
    env.reset(seed=1)
    no_hip = np.array([0.0, 0.0, 0.0])  # 25 deg, no hip torque: the hopper slows down and turns back
    for _ in range(20):
        observation, reward, terminated, truncated, info = env.step(no_hip)
        if terminated:
            break
    assert terminated and not truncated and reward == 0.0
    assert info["failure"] == "reversal" and math.isnan(info["apex_height"])


def test_truncation_at_the_stride_budget_then_reset_needed() -> None:
    env = ApexHopEnv(policy=PolicySpec.default("energy"), max_strides=3)
    env.reset(seed=2)
    ends = [env.step(np.zeros(3))[2:4] for _ in range(3)]
    assert ends == [(False, False), (False, False), (False, True)]
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(3))


@pytest.mark.parametrize("task", [Task("speed"), Task("height", 1.0, 0.1), Task("energy"), Task("survive")])
def test_rewards_follow_their_formulas_on_the_exact_map(task: Task) -> None:
    env = ApexHopEnv(policy=PolicySpec.default("energy"), task=task)
    observation, _ = env.reset(seed=5)
    y, xdot = observation[:2]  # no sensing noise: the measured apex is the true one
    p = PAPER_PARAMS
    for action in np.random.default_rng(1).uniform(-0.2, 0.2, (6, 3)):
        _, reward, terminated, _, info = env.step(action)
        exact = apex_return_map(
            p, ApexState(y, xdot), StanceCommand(info["touchdown_angle"], info["tau0"], info["t_f"])
        )
        assert not terminated and exact.apex is not None
        y, xdot = exact.apex.y, exact.apex.xdot
        energy = p.m * (p.g * y + 0.5 * xdot**2)
        tracked = {"speed": xdot, "height": y, "energy": energy}.get(task.name)
        expected = 1.0 if tracked is None else math.exp(-(((tracked - task.target) / task.scale) ** 2))
        assert reward == pytest.approx(expected, rel=1e-6, abs=1e-9)
        assert info["apex_height"] == pytest.approx(y, rel=1e-8)
        assert info["hip_work"] == pytest.approx(exact.energy.hip_work, rel=1e-6, abs=1e-6)


def test_make_vec_gives_the_vector_env() -> None:
    envs = gym.make_vec(ENV_ID, num_envs=3, task="height")
    assert isinstance(envs, ApexHopVectorEnv)
    observation, _ = envs.reset(seed=0)
    assert observation.shape == (3, 3) and np.all(observation[:, 2] == 1.0)  # the height task's target


def test_the_ground_ahead_is_the_episodes_blocks() -> None:
    """Episode e of seed s hops on blocks of seed terrain_seed(s, e) (docs/envs.md)."""
    ahead = (0.5, 1.0, 2.0)
    env = ApexHopEnv(policy=PolicySpec.default("energy"), perturbations=PERTURBED, lookahead=ahead)
    env.reset(seed=4)
    env.reset()  # episode 1
    observation, _, _, _, info = env.step(np.zeros(3))
    blocks = Blocks(sigma=0.04, length=0.5, start=1.0, seed=terrain_seed(4, 1))
    expected = blocks.height(info["x"] + np.array(ahead)) - info["ground"]
    np.testing.assert_allclose(observation[3:], expected, rtol=0.0, atol=1e-15)
    assert np.any(expected != 0.0)


def _hop_on_blocks(
    example: ModuleType, act: Callable[[np.ndarray], np.ndarray], sigma: float, strides: int, seeds: list[int]
) -> tuple[float, float]:
    """The mean return and the share of episodes that survive ``strides`` strides, one episode per seed, of
    the example's task (hold Ebar 3.5 over blocks of ``sigma``) with the residual ``act`` gives the
    measured apexes (lanes, 2)."""
    env, _ = example.environment(len(seeds), sigma, strides)
    observation, _ = env.reset(seed=seeds)
    returns, survived = np.zeros(len(seeds)), np.zeros(len(seeds), dtype=bool)
    running = np.ones(len(seeds), dtype=bool)
    while running.any():
        observation, reward, terminated, truncated, _ = env.step(act(observation[:, :2]))
        returns += np.where(running, reward, 0.0)
        survived |= running & truncated
        running &= ~(terminated | truncated)
    return float(returns.mean()), float(survived.mean())


def test_the_cem_example_learns_a_residual_that_beats_energy_regulation_on_held_out_blocks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """examples/learn_cem.py, 4 small generations (its seed fixed) on 6 cm blocks, where energy regulation
    alone falls in about half the episodes of 15 strides: the saved policy, read back as the ``learned``
    policy's file and hopped here on grounds no generation trained on, survives more often and earns a
    larger return than energy regulation alone (its zero residual)."""
    spec = importlib.util.spec_from_file_location("learn_cem", REPO / "examples" / "learn_cem.py")
    assert spec is not None and spec.loader is not None
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    out = tmp_path / "policy.json"
    sigma, strides = 0.06, 15
    arguments = f"--generations 4 --population 10 --episodes 4 --strides {strides} --sigma {sigma}"
    monkeypatch.setattr(sys, "argv", ["learn_cem.py", *arguments.split(), "--out", str(out)])
    example.main()
    printed = capsys.readouterr().out
    assert "generation   4" in printed and "learned residual" in printed
    residual = learned.load(out)  # the learned policy's file
    assert residual.weights.shape == (3, 3) and residual.base_policy == "energy"
    assert np.any(residual.weights != 0.0)
    held_out = list(range(2_000_000, 2_000_040))
    base = _hop_on_blocks(example, lambda apex: np.zeros((len(apex), 3)), sigma, strides, held_out)
    ours = _hop_on_blocks(
        example, lambda apex: residual.action(apex[:, 0], apex[:, 1]), sigma, strides, held_out
    )
    assert base[1] < 0.75  # energy regulation alone falls often here: there is something to learn
    assert ours[1] > base[1] + 0.2 and ours[0] > base[0] + 1.0, (ours, base)


def test_the_learned_policy_commands_what_the_residual_env_applies(tmp_path: Path) -> None:
    """One source: the residual env on the learned file's base, acted on by the file's residual, applies at
    each measured apex the command the ``learned`` policy answers that apex with."""
    policy = replace(PolicySpec.default(LEARNED), policy_file=learned_file(tmp_path / "policy.json"))
    residual = learned.load(policy.policy_file)
    noisy = Perturbations(sensing=SensingNoise(height=0.01, speed=0.05))  # measured apexes off the true
    env = ApexHopEnv(policy=PolicySpec.default("energy"), task="energy", perturbations=noisy)
    observation, _ = env.reset(seed=3)
    for _ in range(5):
        answered = policy.commands(PAPER_PARAMS, observation[0], observation[1], observation[1])
        action = residual.action(observation[0], observation[1])[0]
        assert np.any(np.abs(action) > 0.05)  # the residual moves the command
        observation, _, terminated, _, info = env.step(action)
        assert [info[name] for name in ("touchdown_angle", "tau0", "t_f")] == list(answered)
        assert not terminated, info["failure"]


def test_the_liftoff_rule_ends_the_ramp_at_the_predicted_liftoff() -> None:
    env = ApexHopEnv(ramp_duration="liftoff")
    assert env.action_space.shape == (2,)
    observation, _ = env.reset(seed=6)
    _, _, _, _, info = env.step(np.array([0.0, -0.3]))
    predicted = ramp_to_liftoff(
        PAPER_PARAMS, observation[0], observation[1], info["touchdown_angle"], info["tau0"]
    )
    assert info["t_f"] == pytest.approx(float(predicted.t_f), rel=1e-12)


def test_a_zero_residual_is_the_policys_command() -> None:
    policy = PolicySpec.default("energy")
    env = ApexHopEnv(policy=policy)
    observation, _ = env.reset(seed=2)
    _, _, _, _, info = env.step(np.zeros(3))
    planned = policy.commands(PAPER_PARAMS, observation[0], observation[1], observation[1])
    applied = [info[name] for name in ("touchdown_angle", "tau0", "t_f")]
    assert applied == pytest.approx([float(field) for field in planned], rel=1e-12)


def test_actions_of_the_wrong_shape_or_not_finite_are_refused_and_change_nothing() -> None:
    vector = ApexHopVectorEnv(2, policy=PolicySpec.default("apex_foot_placement"))
    vector.reset(seed=4)
    transposed = np.array([[0.1, 0.2], [0.0, 0.5], [-0.3, 0.1]])  # (acted, lanes): one lane's column each
    for refused in (transposed, transposed.ravel(), np.array([[np.nan, 0, 0], [0, 0, 0]])):
        with pytest.raises(ValueError, match="actions must"):
            vector.step(refused)
    single = ApexHopEnv(policy=PolicySpec.default("apex_foot_placement"))
    single.reset(seed=4)
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        single.step(np.zeros(2))
    with pytest.raises(ValueError, match="finite"):
        single.step(np.array([np.nan, 0.0, 0.0]))
    # The refused steps left the lanes as a fresh reset does: the same stride follows.
    fresh = ApexHopEnv(policy=PolicySpec.default("apex_foot_placement"))
    fresh.reset(seed=4)
    assert single.step(np.zeros(3))[4] == fresh.step(np.zeros(3))[4]
    fresh_vector = ApexHopVectorEnv(2, policy=PolicySpec.default("apex_foot_placement"))
    fresh_vector.reset(seed=4)
    assert vector.step(transposed.T)[0].tolist() == fresh_vector.step(transposed.T)[0].tolist()


def test_an_action_outside_the_box_acts_as_the_box_s_edge() -> None:
    envs = [ApexHopEnv(**RESIDUAL) for _ in range(2)]
    for env in envs:
        env.reset(seed=8)
    beyond, edge = np.array([4.0, -3.0, 2.0]), np.array([1.0, -1.0, 1.0])
    assert envs[0].step(beyond)[4] == envs[1].step(edge)[4]


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"base": {"policy": "learned", "settings": {}}}, "its base policy must be one of"),
        ({"base": {"policy": "stance_pd_speed_energy", "settings": {}}}, "its base policy must be one of"),
        ({"base": ["energy"]}, '"base" must be'),
        ({"base": {"policy": "energy", "settings": {"touchdown_angle": "abc"}}}, "could not convert"),
        ({"base": {"policy": "energy", "settings": {"touchdown_angel": 0.4}}}, "no setting touchdown_angel"),
        ({"weights": [[0.0, 0.0, float("nan")]] * 3}, "weights must be finite"),
        ({"weights": 3.0}, "weights must be 3 x 3"),
        ({"scale": [0.0, 0.5]}, "scale must be positive"),
        ({"command_low": [1.0, 0.0, 0.3], "command_high": [0.1, 1.0, 0.4]}, "command_low must lie below"),
        ({"half_width": None}, "must have 3 entries"),
        ({"format": "something else"}, "not a tdslip_ros.linear_residual/1 file"),
    ],
)
def test_a_malformed_policy_file_is_refused_naming_the_file_and_the_fault(
    tmp_path: Path, changes: dict, reason: str
) -> None:
    path = malformed_file(tmp_path, **changes)
    with pytest.raises(PolicyError, match="malformed.json: ") as refused:
        check_policy_file(str(path))
    assert reason in str(refused.value)
    policy = replace(PolicySpec.default(LEARNED), policy_file=str(path))
    with pytest.raises(PolicyError):  # what the controller node logs, answering no command
        policy.commands(PAPER_PARAMS, 1.0, 5.0, 5.0)
    top_level_list = tmp_path / "list.json"
    top_level_list.write_text("[1, 2]")
    with pytest.raises(PolicyError, match="not a tdslip_ros.linear_residual/1 file"):
        check_policy_file(str(top_level_list))


def test_the_base_plans_with_the_spec_s_corrections_not_the_file_s(tmp_path: Path) -> None:
    settings = {"corrections": 0}
    path = malformed_file(tmp_path, base={"policy": "energy", "settings": settings})
    by_file = [
        replace(
            PolicySpec.default(LEARNED), policy_file=str(path), corrections=corrections
        ).learned_residual()[1]
        for corrections in (0, 2)
    ]
    assert [spec.corrections for spec in by_file] == [0, 2]


@pytest.mark.parametrize(
    ("settings", "reason"),
    [
        ({"policy": PolicySpec.default("stance_pd_speed_energy")}, "answering with a ramp"),
        ({"residual_half_width": (0.1, 50.0)}, "residual_half_width must be 3"),
        ({"residual_half_width": (-0.1, 50.0, 0.01)}, "residual_half_width must be 3"),
        ({"tolerance": -1.0}, "tolerance must be positive"),
        ({"lookahead": (0.5, math.nan)}, "lookahead distances must be finite"),
        ({"task": Task("speed", target=1e3)}, "outside what the observation can hold"),
    ],
)
def test_a_configuration_that_cannot_serve_is_refused_when_made(settings: dict, reason: str) -> None:
    with pytest.raises(ParameterError, match=reason):
        ApexHopEnv(**settings)


def test_seeds_gymnasium_accepts_are_taken_and_others_refused_clearly() -> None:
    vector = ApexHopVectorEnv(2)
    by_numpy, by_int = vector.reset(seed=np.int64(3))[0], ApexHopVectorEnv(2).reset(seed=3)[0]
    assert by_numpy.tolist() == by_int.tolist()
    for seed in (2**63, -1):
        with pytest.raises(ValueError, match=r"a seed must be an integer in \[0, 2\*\*63\)"):
            vector.reset(seed=[seed, 0])
    ApexHopEnv().reset(seed=2**63 - 1)
