"""AntMaze: the variants on the quadruped, the expert's pieces and its missing-weights error,
and collection cutting an episode at a flip. Nothing here needs the expert's weights file."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest
import torch

from hispo_pl.cli import main
from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.data.datasets import episodes_to_arrays
from hispo_pl.envs import agent_flipped, make_env
from hispo_pl.envs.experts import (
    ANT_ACTION_SCALE,
    ANT_EXPERT_ENV,
    ANT_WEIGHT_KEYS,
    AntGoalPolicy,
    AntMazeExpert,
    ExpertWeightsNotFoundError,
    PointMazeExpert,
    ant_expert_weights_path,
)
from hispo_pl.envs.robotics import RoboticsMazes
from hispo_pl.evaluation import RolloutEvaluator
from hispo_pl.task_families import VARIANTS
from hispo_pl.tasks import parse_task, transform_action, transform_observation

RESET = {"reset_cell": np.array([1, 1]), "goal_cell": np.array([3, 1])}
STEPS = 15


@pytest.fixture(scope="module")
def ant_envs():
    envs = {v: make_env(f"antmaze-umaze-{v}") for v in VARIANTS}
    yield envs
    for env in envs.values():
        env.close()


def _roll(env, actions, seed=7):
    obs, _ = env.reset(seed=seed, options=RESET)
    trajectory = [obs]
    for a in actions:
        obs, *_ = env.step(a)
        trajectory.append(obs)
    return trajectory


def test_ant_body_observation_and_leg_permutation():
    task = parse_task("antmaze-umaze-PA")
    assert (task.env_family.obs_dim, task.env_family.action_dim) == (27, 8)
    # one leg = two actuators: PA shifts the actions by two entries
    np.testing.assert_array_equal(transform_action(task, np.arange(8)), np.roll(np.arange(8), 2))
    assert make_env("antmaze-umaze").observation_space["observation"].shape == (27,)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_wrapped_ant_follows_base_trajectory_and_matches_the_dataset_view(ant_envs, variant):
    """The wrapped ant, fed the dataset's actions as the variant agent sees them, follows the
    base ant's trajectory and observes exactly the dataset's transformed observations."""
    task = parse_task(f"antmaze-umaze-{variant}")
    actions = np.random.default_rng(0).uniform(-1, 1, (STEPS, 8)).astype(np.float32)
    base = _roll(ant_envs["N"], actions)
    episode = SimpleNamespace(
        observations={k: np.stack([o[k] for o in base]) for k in ("observation", "achieved_goal")},
        actions=actions,
    )
    data = episodes_to_arrays([episode]).for_task(task)
    wrapped = _roll(ant_envs[variant], data.actions[:STEPS])
    assert np.linalg.norm(base[-1]["observation"] - base[0]["observation"]) > 0.1  # it moved
    for k, (b, w) in enumerate(zip(base, wrapped, strict=True)):
        np.testing.assert_array_equal(w["achieved_goal"], b["achieved_goal"])
        np.testing.assert_array_equal(
            w["observation"], transform_observation(task, b["observation"])
        )
        np.testing.assert_array_equal(w["observation"].astype(np.float32), data.observations[k])
    if variant in ("IA", "PA"):  # control: the normal actions do not reproduce the trajectory
        diverged = _roll(ant_envs[variant], actions)
        assert not np.allclose(diverged[-1]["observation"], base[-1]["observation"])


# --- the expert, without its weights ---------------------------------------------------------


def _fake_weights(seed: int = 0) -> dict[str, np.ndarray]:
    g = np.random.default_rng(seed)
    shapes = {
        "fc0_weight": (256, 29),
        "fc0_bias": (256,),
        "fc1_weight": (256, 256),
        "fc1_bias": (256,),
        "last_fc_weight": (8, 256),
        "last_fc_bias": (8,),
    }
    return {k: 0.1 * g.standard_normal(s).astype(np.float32) for k, s in shapes.items()}


def test_missing_weights_say_where_to_get_them(tmp_path, monkeypatch):
    missing = tmp_path / "nowhere.npz"
    monkeypatch.setenv(ANT_EXPERT_ENV, str(missing))
    with pytest.raises(ExpertWeightsNotFoundError) as err:
        ant_expert_weights_path()
    message = str(err.value)
    assert str(missing) in message and ANT_EXPERT_ENV in message and "D4RL" in message
    with pytest.raises(ExpertWeightsNotFoundError):
        AntMazeExpert(make_env("antmaze-umaze"))
    # an explicit path wins over the environment variable
    path = tmp_path / "weights.npz"
    np.savez(path, **_fake_weights())
    assert ant_expert_weights_path(path) == path.resolve()


# collect two ant episodes with the given weights and print the digest of what was stored
_COLLECT_AND_DIGEST = """
import sys
from hispo_pl.cli import main
from hispo_pl.data.datasets import load_episodes
generate = ["data", "generate", "antmaze-umaze", "--episodes", "2"]
assert main([*generate, "--expert-weights", sys.argv[1]]) == 0
print(load_episodes("antmaze-umaze-N[2]").content_digest())
"""


@pytest.mark.skipif(platform.machine() != "x86_64", reason="OpenBLAS's kernel names are x86-64's")
def test_ant_collection_does_not_depend_on_the_processors_blas_kernel(tmp_path):
    """A dataset made again on another machine holds the same episodes only if the expert's
    actions do not depend on the matrix kernel OpenBLAS picks for the processor. Prescott's
    (SSE3, which every x86-64 runs) against the one picked for this processor."""
    weights = tmp_path / "weights.npz"
    np.savez(weights, **_fake_weights())
    digests = {}
    for kernel in ("picked", "Prescott"):
        env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
        env["MINARI_DATASETS_PATH"] = str(tmp_path / f"minari-{kernel}")
        if kernel != "picked":
            env["OPENBLAS_CORETYPE"] = kernel
        done = subprocess.run(
            [sys.executable, "-c", _COLLECT_AND_DIGEST, str(weights)],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        )
        digests[kernel] = done.stdout.split()[-1]
    assert digests["picked"] == digests["Prescott"]


def test_generate_without_weights_fails_with_the_message(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    missing = tmp_path / "nowhere.npz"
    code = main(["data", "generate", "antmaze-umaze", "--expert-weights", str(missing)])
    assert code == 2
    err = capsys.readouterr().err
    assert "AntMaze expert weights not found" in err and str(missing) in err
    assert not (tmp_path / "minari" / "hispo").exists()  # nothing half-made


def test_expert_input_and_action_scale(tmp_path):
    path = tmp_path / "weights.npz"
    np.savez(path, **_fake_weights())
    env = make_env("antmaze-umaze")
    expert = AntMazeExpert(env, path)
    obs, _ = env.reset(seed=0, options=RESET)
    x = expert.policy_input(obs)
    assert x.shape == (29,)
    np.testing.assert_array_equal(x[:27], obs["observation"])
    assert np.linalg.norm(x[27:]) == pytest.approx(10.0)  # the direction, rescaled to length 10
    waypoint = expert.planner.waypoint(obs["achieved_goal"], obs["desired_goal"])
    direction = waypoint - obs["achieved_goal"]
    np.testing.assert_allclose(x[27:], 10 * direction / np.linalg.norm(direction))
    action = expert.act(obs)
    np.testing.assert_allclose(action, ANT_ACTION_SCALE * AntGoalPolicy(_fake_weights())(x))
    assert np.abs(action).max() <= ANT_ACTION_SCALE
    with pytest.raises(ValueError, match="lack"):
        AntGoalPolicy({k: v for k, v in _fake_weights().items() if k != ANT_WEIGHT_KEYS[0]})


def test_collection_cuts_an_episode_at_the_flip(tmp_path):
    """An ant turned over during its 12th action leaves 11 kept transitions and the flag set;
    the ball, which cannot flip, runs its whole episode."""
    path = tmp_path / "weights.npz"
    np.savez(path, **_fake_weights())

    class TurnsOverAt(AntMazeExpert):
        def __init__(self, env, at):
            super().__init__(env, path)
            self.env, self.at, self.calls = env, at, 0

        def act(self, obs):
            self.calls += 1
            if self.calls == self.at:
                _turn_over(self.env)
            return super().act(obs)

    env = make_env("antmaze-umaze", continuing_task=True, reset_target=True)
    rng = np.random.default_rng(0)
    collect_episode = RoboticsMazes().collect_episode
    ep = collect_episode(env, TurnsOverAt(env, 12), rng, seed=0, noise=0.04, steps=50)
    assert len(ep["actions"]) == 11 and len(ep["observation"]) == 12 and bool(ep["flipped"])
    ball = make_env("pointmaze-umaze", continuing_task=True, reset_target=True)
    full = collect_episode(ball, PointMazeExpert(ball), rng, seed=0, noise=0.1, steps=50)
    assert len(full["actions"]) == 50 and not bool(full["flipped"])


def _turn_over(env) -> None:
    """Put the ant on its back (half a turn about x), raised so it lands there."""
    ant = env.unwrapped.ant_env
    ant.data.qpos[2] = 1.0
    ant.data.qpos[3:7] = (0.0, 1.0, 0.0, 0.0)
    mujoco.mj_forward(ant.model, ant.data)


def test_flips_are_detected_from_the_simulator_in_any_variant():
    env = make_env("antmaze-umaze-PO")
    env.reset(seed=0, options=RESET)
    assert not agent_flipped(env)
    _turn_over(env)
    assert agent_flipped(env)
    assert not agent_flipped(make_env("pointmaze-umaze"))


def test_evaluation_counts_and_ends_flipped_episodes():
    evaluator = RolloutEvaluator("antmaze-umaze-IO", episodes=3, seed=0, max_episode_steps=20)
    calls = []

    def policy(observation, position, goal, velocity=None):
        if not calls:  # at the first step, turn the first episode's ant over
            _turn_over(evaluator.envs[0])
        calls.append(len(observation))
        return torch.zeros(len(observation), 8)

    result = evaluator.run(policy)
    assert result.flips.tolist() == [True, False, False] and result.flip_rate == pytest.approx(
        1 / 3
    )
    assert result.lengths[0] == 1 and not result.successes[0]  # it ended at the flip
    assert calls[1] == 2  # the other two episodes went on without it


def test_a_stream_datamodule_takes_its_sizes_from_the_stream():
    """``data.stream: antmaze-2`` alone builds the module for the ant (27 / 8), not for the
    default PointMaze task; a stream mixing families is refused."""
    dm = TaskDataModule(stream="antmaze-2")
    assert dm.task == parse_task("antmaze-umaze-PA[500]")
    assert (dm.obs_dim, dm.action_dim) == (27, 8)
    assert TaskDataModule().task == parse_task("pointmaze-umaze-N[500]")
    with pytest.raises(ValueError, match="one environment family"):
        TaskDataModule(stream=["pointmaze-umaze-N[3]", "antmaze-umaze-N[3]"])
