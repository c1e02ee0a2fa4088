"""HER relabelling by index arithmetic, and the batch sampler built on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hispo_pl.data.datasets import EpisodeArrays, goal_segment_ends
from hispo_pl.data.sampler import HERConfig, HERSampler, relabel_indices
from hispo_pl.tasks import parse_task, transform_observation

LENGTHS = [2, 7, 60, 400, 3, 150]  # rows per episode (T + 1)


def _episode_end(lengths) -> np.ndarray:
    ends = np.cumsum(lengths) - 1
    return np.repeat(ends, lengths).astype(np.int64)


def _sample_index(episode_end: np.ndarray) -> np.ndarray:
    rows = np.arange(len(episode_end))
    return rows[rows != episode_end]


def _segment_end(episode_end: np.ndarray) -> np.ndarray:
    """Two goal segments per episode: the first ends halfway through."""
    rows = np.arange(len(episode_end))
    first_row = np.r_[True, episode_end[1:] != episode_end[:-1]]
    start = np.maximum.accumulate(np.where(first_row, rows, 0))
    mid = (start + episode_end) // 2
    return np.where(rows <= mid, mid, episode_end)


def _indexed_dataset(lengths=LENGTHS, obs_dim=3, act_dim=2) -> EpisodeArrays:
    """A dataset whose every feature encodes its row number, so batches reveal their rows."""
    end = _episode_end(lengths)
    rows = np.arange(len(end), dtype=np.float32)
    return EpisodeArrays(
        observations=np.stack([rows + 0.25 * d for d in range(obs_dim)], axis=1),
        positions=np.stack([rows, -rows], axis=1),
        actions=np.stack([rows + 0.5 * d for d in range(act_dim)], axis=1),
        episode_end=end,
        sample_index=_sample_index(end),
        segment_end=_segment_end(end),
    )


# --- relabel_indices ---------------------------------------------------------------------


@pytest.mark.parametrize("strategy", ["exponential", "uniform", "geometric"])
@pytest.mark.parametrize("waysteps", [1, 5, 50])
def test_goals_and_subgoals_stay_in_episode(strategy, waysteps):
    end = _episode_end(LENGTHS)
    rng = np.random.default_rng(0)
    index = rng.choice(_sample_index(end), 20_000)
    cfg = HERConfig(waysteps=waysteps, temperature=30.0, strategy=strategy, jitter=2)
    goal, subgoal = relabel_indices(index, end, cfg, rng)
    assert goal.shape == subgoal.shape == index.shape
    assert goal.dtype.kind == subgoal.dtype.kind == "i"
    for j in (goal, subgoal):
        assert np.all(j >= index)
        assert np.all(j <= end[index])
        assert np.all(end[j] == end[index])  # same episode
    # subgoal = clip(i + waysteps + jitter, i, end) with |jitter| <= 2
    raw = index + waysteps + np.arange(-2, 3)[:, None]  # every admissible jitter
    admissible = np.clip(raw, index, end[index])
    assert np.all((admissible == subgoal).any(axis=0))


def test_subgoal_jitter_is_uniform_in_range():
    end = _episode_end([100_000])
    rng = np.random.default_rng(1)
    index = rng.integers(0, 50_000, 50_000)  # far from the end: no clipping
    goal, subgoal = relabel_indices(index, end, HERConfig(waysteps=25, jitter=2), rng)
    jitter = subgoal - index - 25
    values, counts = np.unique(jitter, return_counts=True)
    np.testing.assert_array_equal(values, [-2, -1, 0, 1, 2])
    np.testing.assert_allclose(counts / len(index), 0.2, atol=0.01)

    _, sub0 = relabel_indices(index, end, HERConfig(waysteps=25, jitter=0), rng)
    np.testing.assert_array_equal(sub0, index + 25)


def test_subgoal_clipped_at_episode_end():
    end = _episode_end([10, 10])
    index = np.array([0, 5, 8, 10, 18])
    _, subgoal = relabel_indices(index, end, HERConfig(waysteps=50), np.random.default_rng(0))
    np.testing.assert_array_equal(subgoal, [9, 9, 9, 19, 19])


@pytest.mark.parametrize("temperature", [20.0, 100.0])
def test_exponential_offsets_have_mean_temperature(temperature):
    end = _episode_end([1_000_000])
    rng = np.random.default_rng(2)
    index = rng.integers(0, 1000, 200_000)
    cfg = HERConfig(temperature=temperature, strategy="exponential")
    goal, _ = relabel_indices(index, end, cfg, rng)
    offset = goal - index
    # std of the mean is temperature / sqrt(n) ~ 0.002 * temperature
    assert offset.mean() == pytest.approx(temperature, rel=0.02)
    assert np.median(offset) == pytest.approx(temperature * np.log(2), rel=0.03)
    assert offset.min() == 0  # the current row itself can be the goal


def test_exponential_offsets_are_clipped_by_short_episodes():
    end = _episode_end([11] * 1000)
    index = np.arange(0, 11_000, 11)  # first row of each episode, 10 steps to its end
    goal, _ = relabel_indices(index, end, HERConfig(temperature=100.0), np.random.default_rng(3))
    offset = goal - index
    assert offset.max() == 10
    assert (offset == 10).mean() > 0.8  # exp(-10/100) ~ 0.9 of offsets exceed the episode


def test_geometric_offsets_mean_and_minimum():
    end = _episode_end([1_000_000])
    rng = np.random.default_rng(4)
    index = rng.integers(0, 1000, 100_000)
    goal, _ = relabel_indices(index, end, HERConfig(temperature=50.0, strategy="geometric"), rng)
    offset = goal - index
    assert offset.min() >= 1
    assert offset.mean() == pytest.approx(50.0, rel=0.03)


def test_uniform_strategy_covers_the_rest_of_the_episode():
    end = _episode_end([3, 11, 4])
    index = np.full(22_000, 3)  # first row of the 11-row episode: offsets 0..10
    goal, _ = relabel_indices(index, end, HERConfig(strategy="uniform"), np.random.default_rng(5))
    values, counts = np.unique(goal, return_counts=True)
    np.testing.assert_array_equal(values, np.arange(3, 14))
    np.testing.assert_allclose(counts / len(index), 1 / 11, atol=0.01)

    last_but_one = np.full(1000, 12)
    goal, _ = relabel_indices(
        last_but_one, end, HERConfig(strategy="uniform"), np.random.default_rng(6)
    )
    assert set(np.unique(goal)) == {12, 13}


def test_relabel_is_deterministic_per_rng_seed():
    end = _episode_end(LENGTHS)
    index = _sample_index(end)
    cfg = HERConfig(waysteps=10, temperature=20.0)
    a = relabel_indices(index, end, cfg, np.random.default_rng(7))
    b = relabel_indices(index, end, cfg, np.random.default_rng(7))
    c = relabel_indices(index, end, cfg, np.random.default_rng(8))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[0], c[0])


def test_unknown_strategy_raises():
    end = _episode_end([5])
    with pytest.raises(ValueError, match="unknown HER strategy"):
        relabel_indices(np.array([0]), end, HERConfig(strategy="nope"), np.random.default_rng(0))


def test_her_config_defaults():
    cfg = HERConfig()
    assert (cfg.waysteps, cfg.temperature, cfg.strategy, cfg.jitter) == (
        50,
        100.0,
        "exponential",
        2,
    )


# --- HERSampler --------------------------------------------------------------------------


def test_sampler_keys_shapes_dtypes():
    data = _indexed_dataset(obs_dim=3, act_dim=2)
    sampler = HERSampler(data, HERConfig(waysteps=5, temperature=10.0), batch_size=64, seed=0)
    batch = sampler.sample()
    keys = {"observation", "position", "agent_position", "velocity", "goal", "subgoal", "action"}
    assert set(batch) == keys
    shapes = {"observation": 3, "velocity": 2, "goal": 2, "subgoal": 2, "action": 2}
    shapes |= {"position": 2, "agent_position": 2}
    for key, dim in shapes.items():
        assert isinstance(batch[key], torch.Tensor)
        assert batch[key].shape == (64, dim), key
        assert batch[key].dtype == torch.float32, key
    assert sampler.sample(17)["goal"].shape == (17, 2)


@pytest.mark.parametrize("strategy", ["exponential", "uniform", "geometric"])
def test_sampler_rows_are_consistent(strategy):
    data = _indexed_dataset()
    cfg = HERConfig(waysteps=8, temperature=15.0, strategy=strategy)
    batch = HERSampler(data, cfg, batch_size=4096, seed=1).sample()
    i = batch["observation"][:, 0].numpy().astype(np.int64)  # the sampled row
    np.testing.assert_array_equal(batch["observation"].numpy(), data.observations[i])
    np.testing.assert_array_equal(batch["action"].numpy(), data.actions[i])
    np.testing.assert_array_equal(batch["position"].numpy(), data.positions[i])
    assert np.isin(i, data.sample_index).all()  # never an episode's final (action-less) row
    assert len(np.unique(i)) > 300  # rows are spread over the dataset
    goal = batch["goal"][:, 0].numpy().astype(np.int64)
    subgoal = batch["subgoal"][:, 0].numpy().astype(np.int64)
    for j, key in ((goal, "goal"), (subgoal, "subgoal")):
        # the relabelled targets are the positions of real rows of the same episode, ahead of i
        np.testing.assert_array_equal(batch[key].numpy(), data.positions[j])
        assert np.all(j >= i) and np.all(j <= data.episode_end[i])
    ok = subgoal - i - 8
    unclipped = i + 10 <= data.episode_end[i]
    assert np.all(np.abs(ok[unclipped]) <= 2)
    assert np.all(
        subgoal[~unclipped] >= np.minimum(i[~unclipped] + 6, data.episode_end[i][~unclipped])
    )


def test_sampler_is_deterministic_per_seed():
    data = _indexed_dataset()
    cfg = HERConfig(waysteps=5, temperature=10.0)
    a = [HERSampler(data, cfg, batch_size=128, seed=3).sample() for _ in range(2)]
    b = HERSampler(data, cfg, batch_size=128, seed=4).sample()
    for key in a[0]:
        assert torch.equal(a[0][key], a[1][key])
    assert not torch.equal(a[0]["observation"], b["observation"])
    # successive batches of one sampler differ
    sampler = HERSampler(data, cfg, batch_size=128, seed=3)
    first, second = sampler.sample(), sampler.sample()
    assert torch.equal(first["goal"], a[0]["goal"])
    assert not torch.equal(first["observation"], second["observation"])


def test_sampler_on_variant_data(tiny_umaze):
    """On real data in the PO variant, observations are permuted but positions and goals are
    still maze coordinates from the sampled row's own episode."""
    task = parse_task("pointmaze-umaze-PO")
    data = tiny_umaze.for_task(task)
    batch = HERSampler(data, HERConfig(waysteps=50, temperature=100.0), batch_size=256).sample()
    obs = batch["observation"].numpy()
    # undo PO (a cyclic shift by one): the first two base features are the position
    np.testing.assert_array_equal(np.roll(obs, -1, axis=-1)[:, :2], batch["position"].numpy())
    np.testing.assert_array_equal(transform_observation(task, np.roll(obs, -1, axis=-1)), obs)
    for row_obs, goal in zip(obs, batch["goal"].numpy(), strict=True):
        i = int(np.flatnonzero((data.observations == row_obs).all(axis=1))[0])
        episode = slice(i, int(data.episode_end[i]) + 1)
        assert (data.positions[episode] == goal).all(axis=1).any()


# --- goal segments -------------------------------------------------------------------------


def test_goal_segment_ends_mark_where_each_goal_was_reached():
    goals = np.array([[0, 0], [0, 0], [1, 1], [1, 1], [1, 1], [2, 2]], dtype=float)
    np.testing.assert_array_equal(goal_segment_ends(goals), [2, 2, 5, 5, 5, 5])
    np.testing.assert_array_equal(goal_segment_ends(np.zeros((4, 2))), [3, 3, 3, 3])


@pytest.mark.parametrize("strategy", ["exponential", "uniform", "geometric"])
def test_segment_horizon_keeps_goals_in_their_segment_but_not_subgoals(strategy):
    data = _indexed_dataset()
    cfg = HERConfig(waysteps=40, temperature=200.0, strategy=strategy, goal_horizon="segment")
    index = data.sample_index
    goal, subgoal = relabel_indices(
        index, data.episode_end, cfg, np.random.default_rng(0), data.segment_end
    )
    assert (goal >= index).all() and (goal <= data.segment_end[index]).all()
    assert (subgoal <= data.episode_end[index]).all()
    assert (subgoal > data.segment_end[index]).any()  # subgoals still run across goal switches
    episode_goal, _ = relabel_indices(
        index, data.episode_end, HERConfig(40, 200.0, strategy), np.random.default_rng(0)
    )
    assert (episode_goal > data.segment_end[index]).any()  # the reference horizon does cross


def test_segment_horizon_needs_segment_ends():
    data = _indexed_dataset()
    with pytest.raises(ValueError, match="segment_end"):
        relabel_indices(
            data.sample_index,
            data.episode_end,
            HERConfig(goal_horizon="segment"),
            np.random.default_rng(0),
        )


def test_sampler_uses_segment_ends(tmp_path):
    data = _indexed_dataset()
    sampler = HERSampler(data, HERConfig(5, 500.0, goal_horizon="segment"), batch_size=512)
    batch = sampler.sample()
    rows = batch["position"][:, 0].long().numpy()
    goal_rows = batch["goal"][:, 0].long().numpy()
    assert (goal_rows <= data.segment_end[rows]).all()


def test_transitions_add_the_next_row_and_leave_the_batch_unchanged():
    data = _indexed_dataset()
    cfg = HERConfig(waysteps=5, temperature=10.0)
    plain = HERSampler(data, cfg, batch_size=512, seed=7)
    with_next = HERSampler(data, cfg, batch_size=512, seed=7, transitions=True)
    for _ in range(2):  # the option draws nothing more: every batch stays the same
        a, b = plain.sample(), with_next.sample()
        assert set(b) - set(a) == {"next_observation", "next_position"}
        for key in a:
            assert torch.equal(a[key], b[key]), key
        i = b["observation"][:, 0].numpy().astype(np.int64)
        np.testing.assert_array_equal(b["next_observation"].numpy(), data.observations[i + 1])
        np.testing.assert_array_equal(b["next_position"].numpy(), data.positions[i + 1])
        assert np.all(i + 1 <= data.episode_end[i])  # the next row is in the same episode
