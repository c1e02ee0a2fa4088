"""Acceptance test of the variants: the env wrapper and the dataset transform agree.

A wrapped env driven by ``transform_action(a)`` must follow exactly the base env's trajectory
under ``a``, seeing ``transform_observation`` of the base observation; and a dataset recorded
on the base env, viewed through ``EpisodeArrays.for_task``, must hold exactly what the wrapped
env shows and what it must be fed.
"""

from __future__ import annotations

from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest

from hispo_pl.data.datasets import episodes_to_arrays
from hispo_pl.envs import VariantWrapper, make_env
from hispo_pl.task_families import VARIANTS
from hispo_pl.tasks import parse_task, transform_action, transform_observation

RESET = {"reset_cell": np.array([1, 1]), "goal_cell": np.array([3, 1])}
SEED = 123


@pytest.fixture(scope="module")
def pointmaze_envs():
    """One base env and one wrapped env per variant, built once for this module."""
    envs = {"base": make_env("pointmaze-umaze")}
    for v in VARIANTS:
        envs[v] = make_env(f"pointmaze-umaze-{v}")
    yield envs
    for env in envs.values():
        env.close()


def _random_actions(n: int, dim: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (n, dim))


def _roll(env, actions, seed=SEED, options=RESET):
    """Observations (T + 1 dicts) of ``env`` under ``actions`` from a seeded reset."""
    obs, _ = env.reset(seed=seed, options=options)
    trajectory = [obs]
    for a in actions:
        obs, _, terminated, truncated, _ = env.step(a)
        trajectory.append(obs)
        assert not (terminated or truncated)
    return trajectory


def _variant_wrapper(env):
    """The VariantWrapper in ``env``'s wrapper chain, or None."""
    while isinstance(env, gym.Wrapper):
        if isinstance(env, VariantWrapper):
            return env
        env = env.env
    return None


def test_wrapper_only_for_non_normal_variants(pointmaze_envs):
    assert _variant_wrapper(pointmaze_envs["N"]) is None
    for v in ("IA", "IO", "PA", "PO"):
        wrapper = _variant_wrapper(pointmaze_envs[v])
        assert wrapper is not None
        assert wrapper.task == parse_task(f"pointmaze-umaze-{v}")


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_wrapped_env_follows_base_trajectory(pointmaze_envs, variant):
    task = parse_task(f"pointmaze-umaze-{variant}")
    base, wrapped = pointmaze_envs["base"], pointmaze_envs[variant]
    actions = _random_actions(60, 2)
    base_traj = _roll(base, actions)
    wrapped_traj = _roll(wrapped, [transform_action(task, a) for a in actions])

    moved = np.linalg.norm(base_traj[-1]["achieved_goal"] - base_traj[0]["achieved_goal"])
    assert moved > 0.05  # the random actions really move the ball
    for b, w in zip(base_traj, wrapped_traj, strict=True):
        np.testing.assert_array_equal(w["achieved_goal"], b["achieved_goal"])
        np.testing.assert_array_equal(w["desired_goal"], b["desired_goal"])  # goals unchanged
        np.testing.assert_array_equal(
            w["observation"], transform_observation(task, b["observation"])
        )
    if variant in ("IO", "PO"):  # the agent really sees different features
        assert not np.allclose(wrapped_traj[-1]["observation"], base_traj[-1]["observation"])


@pytest.mark.parametrize("variant", ["IA", "PA"])
def test_untransformed_actions_diverge(pointmaze_envs, variant):
    """Control: feeding a variant env the *normal* actions does not reproduce the trajectory,
    so the previous test is not trivially satisfied."""
    base, wrapped = pointmaze_envs["base"], pointmaze_envs[variant]
    actions = _random_actions(30, 2, seed=1)
    base_traj = _roll(base, actions)
    wrapped_traj = _roll(wrapped, actions)
    gap = np.linalg.norm(base_traj[-1]["achieved_goal"] - wrapped_traj[-1]["achieved_goal"])
    assert gap > 1e-3


def _record_episodes(env, n_episodes: int, steps: int):
    """Minari-like episodes recorded on the base env with random actions."""
    episodes = []
    for k in range(n_episodes):
        actions = _random_actions(steps, 2, seed=10 + k).astype(np.float32)
        traj = _roll(env, actions, seed=SEED + k)
        observations = {
            key: np.stack([o[key] for o in traj]) for key in ("observation", "achieved_goal")
        }
        episodes.append(SimpleNamespace(observations=observations, actions=actions, seed=SEED + k))
    return episodes


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_dataset_view_matches_wrapped_env(pointmaze_envs, variant):
    """The achieved goals are compared exactly: both rollouts run on one simulator in one
    process, and a variant's transforms only permute and negate."""
    task = parse_task(f"pointmaze-umaze-{variant}")
    steps = 40
    episodes = _record_episodes(pointmaze_envs["base"], 2, steps)
    data = episodes_to_arrays(episodes).for_task(task)
    assert data.observations.shape == (2 * (steps + 1), 4)
    wrapped = pointmaze_envs[variant]
    start = 0
    for ep in episodes:
        rows = slice(start, start + steps + 1)
        fed = data.actions[rows][:steps]  # the dataset's actions, as the variant agent outputs them
        traj = _roll(wrapped, fed, seed=ep.seed)
        seen = np.stack([o["observation"] for o in traj])
        np.testing.assert_allclose(data.observations[rows], seen, rtol=0, atol=1e-5)  # float32
        np.testing.assert_array_equal(
            data.actions[rows][:steps], transform_action(task, ep.actions)
        )
        np.testing.assert_allclose(
            data.positions[rows], np.stack([o["achieved_goal"] for o in traj]), rtol=0, atol=1e-5
        )
        # the dataset's achieved goals are the wrapped env's, i.e. the base trajectory
        np.testing.assert_allclose(
            np.stack([o["achieved_goal"] for o in traj]),
            ep.observations["achieved_goal"],
            rtol=0,
            atol=0,
        )
        start += steps + 1


# --- AntMaze -----------------------------------------------------------------------------


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_antmaze_transforms_on_arrays(variant):
    task = parse_task(f"antmaze-umaze-{variant}")
    rng = np.random.default_rng(2)
    ep = SimpleNamespace(
        observations={
            "observation": rng.normal(size=(6, 27)),
            "achieved_goal": rng.normal(size=(6, 2)),
        },
        actions=rng.uniform(-1, 1, (5, 8)).astype(np.float32),
    )
    base = episodes_to_arrays([ep])
    data = base.for_task(task)
    assert data.observations.shape == (6, 27) and data.actions.shape == (6, 8)
    np.testing.assert_array_equal(data.positions, base.positions)
    np.testing.assert_array_equal(data.episode_end, base.episode_end)
    np.testing.assert_array_equal(data.sample_index, base.sample_index)
    obs, act = base.observations, base.actions
    expected_obs = {"IO": -obs, "PO": np.concatenate([obs[:, -1:], obs[:, :-1]], axis=1)}
    expected_act = {"IA": -act, "PA": np.concatenate([act[:, -2:], act[:, :-2]], axis=1)}
    np.testing.assert_array_equal(data.observations, expected_obs.get(variant, obs))
    np.testing.assert_array_equal(data.actions, expected_act.get(variant, act))


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_antmaze_wrapped_env_follows_base_trajectory(variant):
    task = parse_task(f"antmaze-umaze-{variant}")
    base, wrapped = make_env("antmaze-umaze"), make_env(task)
    try:
        assert base.observation_space["observation"].shape == (27,)
        assert base.action_space.shape == (8,)
        actions = _random_actions(20, 8, seed=3)
        base_traj = _roll(base, actions)
        wrapped_traj = _roll(wrapped, [transform_action(task, a) for a in actions])
        for b, w in zip(base_traj, wrapped_traj, strict=True):
            np.testing.assert_array_equal(w["achieved_goal"], b["achieved_goal"])
            np.testing.assert_array_equal(
                w["observation"], transform_observation(task, b["observation"])
            )
        if variant in ("IA", "PA"):
            other = _roll(wrapped, actions)  # normal actions in a variant env: a different body
            assert not np.allclose(other[-1]["observation"], wrapped_traj[-1]["observation"])
    finally:
        base.close()
        wrapped.close()


# --- the real generated dataset, replayed through the wrapped env -------------------------


def _collection_reset(env, k: int, seed: int = 0):
    """The reset of episode ``k`` of a dataset generated with ``seed`` (as documented:
    episodes are seeded by (seed, index): start/goal cells from default_rng([seed, k]))."""
    from hispo_pl.envs.mazes import free_cells, maze_array

    cells = free_cells(maze_array(env))
    i, j = np.random.default_rng([seed, k]).choice(len(cells), size=2, replace=False)
    options = {"reset_cell": cells[i], "goal_cell": cells[j]}
    return env.reset(seed=seed * 1_000_003 + k, options=options)[0]


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_generated_dataset_replays_in_wrapped_env(tiny_umaze, variant):
    """Episode 1 of the real generated dataset, viewed through ``for_task``: feeding its
    actions to the variant env reproduces its observations (up to float32 storage)."""
    task = parse_task(f"pointmaze-umaze-{variant}")
    data = tiny_umaze.for_task(task)
    k = 1
    first = int(tiny_umaze.episode_end[0]) + 1
    last = int(tiny_umaze.episode_end[first])
    env = make_env(task, continuing_task=True, reset_target=True)
    try:
        obs = _collection_reset(env, k)
        errors = [np.abs(obs["observation"] - data.observations[first]).max()]
        for row in range(first, last):
            obs, *_ = env.step(data.actions[row])
            errors.append(np.abs(obs["observation"] - data.observations[row + 1]).max())
            np.testing.assert_allclose(obs["achieved_goal"], data.positions[row + 1], atol=1e-4)
        assert len(errors) == last - first + 1 == 301
        assert max(errors) < 1e-4
        if variant in ("IA", "PA"):  # the stored normal actions do not fit the variant env
            obs = _collection_reset(env, k)
            for row in range(first, first + 50):
                obs, *_ = env.step(tiny_umaze.actions[row])
            assert np.abs(obs["achieved_goal"] - data.positions[first + 50]).max() > 1e-2
    finally:
        env.close()


def test_every_task_is_a_gymnasium_id():
    """``import hispo_pl.envs`` registers each maze variant and game maze with Gymnasium."""
    import hispo_pl.envs  # noqa: F401
    from hispo_pl.task_families import FAMILIES

    for family, fam in FAMILIES.items():
        for maze, defaults in fam.mazes.items():
            for variant in fam.variants:
                spec = gym.spec(parse_task(f"{family}-{maze}-{variant}").gym_id)
                assert spec.max_episode_steps == defaults.max_episode_steps


def test_gym_make_of_a_variant_id_is_the_task(pointmaze_envs):
    env = gym.make("hispo_pl/PointMaze_UMaze-PO-v3")
    task = parse_task("pointmaze-umaze-PO")
    actions = _random_actions(30, 2, seed=1)
    made = _roll(env, [transform_action(task, a) for a in actions])
    base = _roll(pointmaze_envs["base"], actions)
    for b, m in zip(base, made, strict=True):
        np.testing.assert_array_equal(
            m["observation"], transform_observation(task, b["observation"])
        )
    assert env.spec.max_episode_steps == task.defaults.max_episode_steps
    env.close()


def test_gym_make_of_a_game_id():
    env = gym.make("hispo_pl/AmazeVille_HOOO-v0")
    obs, _ = env.reset(seed=0)
    assert obs["observation"].shape == (127,)
    env.close()
