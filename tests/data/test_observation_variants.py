"""An observation variant (IO, PO) reaches the agent under every input option a run accepts:
in the same state, an IO/PO task's policy inputs differ from its N task's; and a choice of
inputs under which no policy would tell them apart is refused when the run is configured.

The exact comparisons here are made within one process on the same data: a variant only
negates, shifts and slices values, so equal inputs are equal bit for bit on any CPU."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers import tiny_stream_args

from hispo_pl.cli import main
from hispo_pl.config import BackboneConfig
from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.data.datasets import EpisodeArrays
from hispo_pl.data.sampler import HERConfig, HERSampler
from hispo_pl.errors import ConfigError
from hispo_pl.nn.hierarchy import HierarchicalPolicy
from hispo_pl.task_families import FAMILIES, HIGH_INPUTS, LOW_INPUTS, OBSERVATION_VARIANTS
from hispo_pl.tasks import parse_task, unseen_variant_tasks

# every family whose agent has observation variants, and every input option of the configs
VARIANT_FAMILIES = [
    name for name, f in FAMILIES.items() if set(OBSERVATION_VARIANTS) <= set(f.variants)
]
LOW = ["family", *LOW_INPUTS]
HIGH = ["family", *HIGH_INPUTS]


def _episodes(
    obs_dim: int,
    action_dim: int,
    goal_dim: int,
    position_in_observation: bool,
    n_episodes: int = 4,
    length: int = 40,
):
    """Random-walk episodes whose observation features are all distinct and non-zero (their
    first ones the position, where the family's observation holds it)."""
    rng = np.random.default_rng(0)
    rows = n_episodes * (length + 1)
    end = np.repeat(np.arange(1, n_episodes + 1) * (length + 1) - 1, length + 1)
    first = np.arange(rows) % (length + 1) == 0
    sample = np.flatnonzero(np.arange(rows) % (length + 1) != length)
    positions = np.cumsum(rng.normal(size=(rows, goal_dim)) * ~first[:, None], 0) + 3.0
    observations = rng.normal(size=(rows, obs_dim)) + 3.0
    if position_in_observation:
        observations[:, :goal_dim] = positions
    return EpisodeArrays(
        observations=observations.astype(np.float32),
        positions=positions.astype(np.float32),
        actions=rng.normal(size=(rows, action_dim)).astype(np.float32),
        episode_end=end.astype(np.int64),
        sample_index=sample.astype(np.int64),
        segment_end=end.astype(np.int64),
    )


def _inputs(dm: TaskDataModule, task: str, data: EpisodeArrays) -> dict[str, torch.Tensor]:
    """Each level's inputs, built by the backbone from a batch of ``task``'s data, for the
    inputs ``dm`` chose; the sampler's seed fixes the rows, so every task sees the same states."""
    task = parse_task(task)
    family = task.env_family
    sampler = HERSampler(
        data.for_task(task),
        HERConfig(waysteps=5, temperature=10.0),
        64,
        seed=3,
        step_seconds=family.step_seconds,
    )
    batch = sampler.sample()
    backbone = BackboneConfig(
        high_hidden=8,
        low_hidden=8,
        low_obs=dm.low_obs,
        low_velocity=dm.low_velocity,
        high_obs=dm.high_obs,
    )
    policy = HierarchicalPolicy(backbone, family.obs_dim, family.action_dim, family.goal_dim)
    return {name: policy.inputs(name, batch)[0] for name in policy.names}


def _levels_reading_the_variant(family: str, low: str, high: str) -> dict[str, bool]:
    """Which levels read something an observation variant moves: the observation, or the
    position (and the velocity made of it) where the family's observation holds it."""
    f = FAMILIES[family]
    low_obs, low_velocity = LOW_INPUTS[f.low_inputs if low == "family" else low]
    high_obs = HIGH_INPUTS[f.high_inputs if high == "family" else high]
    sensed = f.position_in_observation
    return {"high": high_obs or sensed, "low": low_obs or (low_velocity and sensed)}


@pytest.mark.parametrize("high", HIGH)
@pytest.mark.parametrize("low", LOW)
@pytest.mark.parametrize("family", VARIANT_FAMILIES)
def test_observation_variants_reach_the_policies_or_are_refused(family, low, high):
    f = FAMILIES[family]
    maze = next(iter(f.mazes))
    normal = f"{family}-{maze}-N[3]"
    stream = [normal, *(f"{family}-{maze}-{v}[3]" for v in OBSERVATION_VARIANTS)]
    reads = _levels_reading_the_variant(family, low, high)
    if not any(reads.values()):
        with pytest.raises(ConfigError, match="no policy reads the observation"):
            TaskDataModule(stream=stream, low_inputs=low, high_inputs=high)
        return
    dm = TaskDataModule(stream=stream, low_inputs=low, high_inputs=high)
    data = _episodes(f.obs_dim, f.action_dim, f.goal_dim, f.position_in_observation)
    seen = _inputs(dm, normal, data)
    for variant in OBSERVATION_VARIANTS:
        other = _inputs(dm, f"{family}-{maze}-{variant}[3]", data)
        for level, reading in reads.items():
            # a level that reads what the variant moves sees it; one that does not, does not
            assert torch.equal(seen[level], other[level]) is not reading, (variant, level)


def test_only_antmaze_goal_space_inputs_are_refused():
    """PointMaze's policies read the position from the observation, so every option reaches
    them; the ant's position is a channel apart, so goal-space inputs at both levels do not."""
    refused = [
        (family, low, high)
        for family in VARIANT_FAMILIES
        for low in LOW
        for high in HIGH
        if not any(_levels_reading_the_variant(family, low, high).values())
    ]
    assert sorted(refused) == [
        ("antmaze", "goal", "family"),
        ("antmaze", "goal", "goal"),
        ("antmaze", "subgoal", "family"),
        ("antmaze", "subgoal", "goal"),
    ]


@pytest.mark.parametrize("family", VARIANT_FAMILIES)
def test_the_family_defaults_read_what_the_variants_move(family):
    assert any(_levels_reading_the_variant(family, "family", "family").values())


def test_every_named_stream_accepts_its_family_defaults():
    from hispo_pl.tasks import STREAMS

    for name in STREAMS:
        TaskDataModule(stream=name)  # raises if a stream's variants went unseen


def test_unseen_tasks_are_the_observation_variants_only():
    specs = ("N", "IA", "PA", "PO", "IO", "PO")
    tasks = [parse_task(f"antmaze-umaze-{v}") for v in specs]
    assert [t.spec for t in unseen_variant_tasks(tasks, reads_observation=False)] == [
        "antmaze-umaze-PO[500]",
        "antmaze-umaze-IO[500]",
    ]
    # PointMaze's position is in its observation: every policy reads it
    points = [parse_task(f"pointmaze-umaze-{v}") for v in specs]
    assert unseen_variant_tasks(points, reads_observation=False) == []
    assert unseen_variant_tasks(tasks, reads_observation=True) == []


def test_a_single_task_run_of_an_observation_variant_is_refused_too():
    with pytest.raises(ConfigError, match="antmaze-umaze-IO"):
        TaskDataModule("antmaze-umaze-IO[3]", low_inputs="goal", high_inputs="goal")
    TaskDataModule("antmaze-umaze-N[3]", low_inputs="goal", high_inputs="goal")  # N: allowed
    TaskDataModule("pointmaze-umaze-IO[3]", low_inputs="goal", high_inputs="goal")  # sensed


def test_backbone_says_whether_it_reads_the_observation():
    assert BackboneConfig(low_obs=True, high_obs=False).reads_observation
    assert BackboneConfig(low_obs=False, high_obs=True).reads_observation
    assert not BackboneConfig(low_obs=False, high_obs=False).reads_observation
    # the flat policy reads the high policy's inputs only
    assert not BackboneConfig(kind="bc", low_obs=True, high_obs=False).reads_observation


ANT_STREAM = ["antmaze-umaze-N[3]", "antmaze-umaze-PO[3]"]
GOAL_ONLY = ("--data.low_inputs", "goal", "--data.high_inputs", "goal")


def test_fit_refuses_goal_only_inputs_on_a_stream_with_an_observation_variant(tmp_path, capsys):
    code = main(tiny_stream_args("ftn", tmp_path, ANT_STREAM, *GOAL_ONLY))
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert (
        len(err) == 1
        and "antmaze-umaze-PO[3]" in err[0]
        and "--data.low_inputs observation" in err[0]
    )


def test_fit_refuses_a_flat_policy_blind_to_the_variant(tmp_path, capsys):
    code = main(
        tiny_stream_args(
            "bc-ftn",
            tmp_path,
            ANT_STREAM,
            "--data.high_inputs",
            "goal",
            "--data.low_inputs",
            "observation",
        )
    )
    err = capsys.readouterr().err
    assert code == 2 and "flat policy" in err and "antmaze-umaze-PO[3]" in err


def test_pointmaze_senses_its_position_through_the_observation(tiny_umaze):
    """In N the sensed position is the maze position itself (so N tasks train as before); in
    IO it is negated, in PO it is what the shifted observation holds where x, y were."""
    for variant, expected in (
        ("N", tiny_umaze.positions),
        ("IO", -tiny_umaze.positions),
        ("PO", np.stack([tiny_umaze.observations[:, 3], tiny_umaze.positions[:, 0]], axis=1)),
    ):
        arrays = tiny_umaze.for_task(parse_task(f"pointmaze-umaze-{variant}"))
        assert np.array_equal(arrays.agent_positions, expected), variant
        assert np.array_equal(arrays.positions, tiny_umaze.positions)  # targets: maze coordinates


def test_rollouts_hand_the_policy_the_sensed_position():
    from hispo_pl.evaluation import RolloutEvaluator

    seen = []

    def policy(observation, position, goal, velocity):
        seen.append((observation.clone(), position.clone(), velocity.clone()))
        return torch.zeros(len(observation), 2)

    evaluator = RolloutEvaluator("pointmaze-umaze-IO", episodes=2, max_episode_steps=5)
    result = evaluator.run(policy, record=True)
    evaluator.close()
    for observation, position, _ in seen:
        assert torch.equal(position, observation[:, :2])
    first = torch.as_tensor(np.stack([t[0] for t in result.trajectories]), dtype=torch.float32)
    assert torch.equal(seen[0][1], -first)  # IO: the negated maze position
    dt = evaluator.step_seconds
    assert torch.allclose(seen[1][2], (seen[1][1] - seen[0][1]) / dt)
