"""Seeded, vectorised rollout evaluation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hispo_pl import evaluation
from hispo_pl.envs import make_env
from hispo_pl.envs.experts import PointMazeExpert
from hispo_pl.envs.mazes import maze_array
from hispo_pl.envs.robotics import start_goal_cells
from hispo_pl.evaluation import RolloutEvaluator, RolloutResult
from hispo_pl.tasks import parse_task, transform_action


@pytest.fixture(scope="module")
def umaze_grid():
    env = make_env("pointmaze-umaze")
    yield maze_array(env)
    env.close()


@pytest.fixture(scope="module")
def expert():
    env = make_env("pointmaze-umaze")
    yield PointMazeExpert(env)
    env.close()


def expert_policy(expert, task="pointmaze-umaze", observe=lambda o: o):
    """The scripted expert as a batched PolicyFn, acting in ``task``'s variant: ``observe``
    maps the variant's observation features back to the base ones."""
    task = parse_task(task)

    def policy(observation, position, goal, velocity=None):
        actions = []
        for o, g in zip(observation.numpy(), goal.numpy(), strict=True):
            expert.reset()  # one expert serves every row: plan afresh from each row's own cell
            a = expert.act({"observation": observe(o.astype(np.float64)), "desired_goal": g})
            actions.append(transform_action(task, a))
        return torch.as_tensor(np.stack(actions), dtype=torch.float32)

    return policy


def zero_policy(observation, position, goal, velocity=None):
    return torch.zeros(len(observation), 2)


def greedy_policy(observation, position, goal, velocity=None):
    """Heads straight for the goal, ignoring walls: succeeds only sometimes."""
    return torch.clamp(3.0 * (goal - position) - 0.5 * observation[:, 2:4], -1.0, 1.0)


# --- start_goal_cells --------------------------------------------------------------------


def test_start_goal_cells_distinct_free_and_seeded(umaze_grid):
    cells = start_goal_cells(umaze_grid, 200, seed=0)
    assert cells.shape == (200, 2, 2)
    rows, cols = cells[..., 0], cells[..., 1]
    assert np.all(umaze_grid[rows, cols] == 0)  # every start and goal is a free cell
    assert np.all((cells[:, 0] != cells[:, 1]).any(axis=1))  # start != goal
    np.testing.assert_array_equal(start_goal_cells(umaze_grid, 200, seed=0), cells)
    assert not np.array_equal(start_goal_cells(umaze_grid, 200, seed=1), cells)
    # the seed fixes the sequence: fewer episodes give a prefix of the same pairs
    np.testing.assert_array_equal(start_goal_cells(umaze_grid, 20, seed=0), cells[:20])
    # all 7 free cells of the U-maze appear as starts and as goals
    assert len({tuple(c) for c in cells[:, 0]}) == 7 == len({tuple(c) for c in cells[:, 1]})


def test_start_goal_cells_on_a_hand_made_grid():
    grid = np.array([[1, 1, 1, 1], [1, 0, 1, 1], [1, 1, 0, 1], [1, 1, 1, 1]], dtype=np.int8)
    cells = start_goal_cells(grid, 50, seed=3)
    pairs = {tuple(map(tuple, p)) for p in cells}
    assert pairs == {((1, 1), (2, 2)), ((2, 2), (1, 1))}


# --- RolloutEvaluator --------------------------------------------------------------------


def test_expert_policy_reaches_every_goal(expert):
    evaluator = RolloutEvaluator("pointmaze-umaze", episodes=10, seed=0)
    try:
        assert len(evaluator.envs) == 10
        assert evaluator.max_steps == 300  # the maze's default step limit
        result = evaluator.run(expert_policy(expert))
    finally:
        evaluator.close()
    assert isinstance(result, RolloutResult)
    assert result.episodes == 10
    assert result.success == 1.0
    assert result.successes.dtype == bool and result.successes.all()
    # episodes end at success, well before the step limit
    assert result.lengths.shape == (10,)
    assert np.all(result.lengths >= 1) and np.all(result.lengths < 300)
    assert result.episode_length == pytest.approx(result.lengths.mean())


def test_zero_policy_fails_and_runs_to_the_limit():
    evaluator = RolloutEvaluator("pointmaze-umaze", episodes=6, seed=0, max_episode_steps=50)
    try:
        result = evaluator.run(zero_policy)
    finally:
        evaluator.close()
    assert result.success == 0.0
    assert not result.successes.any()
    np.testing.assert_array_equal(result.lengths, np.full(6, 50))
    assert result.episode_length == 50.0


def test_envs_are_reused_and_results_repeat(monkeypatch):
    """Exact: the same seeds twice in one process, on the same environments."""
    evaluator = RolloutEvaluator("pointmaze-umaze", episodes=6, seed=1, max_episode_steps=80)
    try:
        envs = list(evaluator.envs)

        def no_new_envs(*args, **kwargs):
            raise AssertionError("run() must not build environments")

        monkeypatch.setattr(evaluation, "make_env", no_new_envs)
        first = evaluator.run(greedy_policy)
        second = evaluator.run(greedy_policy)
        assert all(a is b for a, b in zip(evaluator.envs, envs, strict=True))
    finally:
        evaluator.close()
    assert first.success == second.success
    np.testing.assert_array_equal(first.successes, second.successes)
    np.testing.assert_array_equal(first.lengths, second.lengths)
    # the greedy policy is a non-trivial probe: it reaches some goals and misses others
    assert 0.0 < first.success < 1.0
    assert first.lengths.min() < 80


def test_fewer_envs_than_episodes_match_one_env_per_episode():
    """With fewer envs than episodes (an env starts the next episode when its own ends) each
    episode is the same as with one env per episode: episodes are seeded by their index, not
    by the env that runs them."""
    kwargs = dict(episodes=5, seed=2, max_episode_steps=60)
    waves = RolloutEvaluator("pointmaze-umaze", max_envs=2, **kwargs)
    single = RolloutEvaluator("pointmaze-umaze", max_envs=5, **kwargs)
    try:
        assert len(waves.envs) == 2 and len(single.envs) == 5
        a, b = waves.run(greedy_policy), single.run(greedy_policy)
    finally:
        waves.close()
        single.close()
    np.testing.assert_array_equal(a.successes, b.successes)
    np.testing.assert_array_equal(a.lengths, b.lengths)
    assert a.episodes == b.episodes == 5
    assert 0.0 < a.success < 1.0 and len(set(a.lengths)) > 2  # episodes really differ


def test_policy_is_called_on_active_episodes_only(expert):
    seen = []
    base = expert_policy(expert)

    def recording(observation, position, goal, velocity=None):
        assert observation.dtype == position.dtype == goal.dtype == torch.float32
        assert observation.shape[1] == 4 and position.shape[1] == goal.shape[1] == 2
        # the position handed to the policy is the ball's, the first two observation features
        assert torch.equal(position, observation[:, :2])
        # the velocity handed to it is the ball's too, from its positions (0 at the start)
        expected = observation[:, 2:] if seen else torch.zeros_like(velocity)
        assert torch.allclose(velocity, expected, atol=1e-3)
        seen.append(len(observation))
        return base(observation, position, goal)

    evaluator = RolloutEvaluator("pointmaze-umaze", episodes=4, seed=5)
    try:
        result = evaluator.run(recording)
    finally:
        evaluator.close()
    assert seen[0] == 4
    assert all(
        x >= y for x, y in zip(seen[:-1], seen[1:], strict=True)
    )  # the batch shrinks as episodes end
    assert len(seen) == result.lengths.max()
    assert sum(seen) == result.lengths.sum()


@pytest.mark.parametrize(
    "variant, observe",
    [
        ("IA", lambda o: o),
        ("PA", lambda o: o),
        ("IO", lambda o: -o),
        ("PO", lambda o: np.roll(o, -1)),
    ],
)
def test_expert_adapted_to_variant_succeeds(expert, variant, observe):
    """The evaluator runs the variant env: the expert succeeds once it undoes the variant."""
    task = f"pointmaze-umaze-{variant}"
    evaluator = RolloutEvaluator(task, episodes=6, seed=0)
    try:
        result = evaluator.run(expert_policy(expert, task, observe))
    finally:
        evaluator.close()
    assert result.success == 1.0


def test_unadapted_expert_fails_on_inverted_actions(expert):
    evaluator = RolloutEvaluator("pointmaze-umaze-IA", episodes=6, seed=0, max_episode_steps=100)
    try:
        result = evaluator.run(expert_policy(expert))  # normal actions into the IA env
    finally:
        evaluator.close()
    assert result.success < 0.5


def test_eval_mode_switches_once_and_restores():
    from hispo_pl.modules import HBC
    from hispo_pl.nn import eval_mode

    module = HBC(4, 2).train()
    with eval_mode(module):
        assert not any(m.training for m in module.modules())
        switches = []
        module.train = lambda mode=True: switches.append(mode)  # a policy call inside
        with eval_mode(module):
            pass
        assert switches == []  # already in eval mode: nothing switched back and forth
        del module.train
    assert all(m.training for m in module.modules())
    module.block = torch.nn.Linear(2, 2)  # a submodule left training switches the whole module
    module.eval()
    module.block.train()
    with eval_mode(module):
        assert not module.block.training
    assert not module.training
