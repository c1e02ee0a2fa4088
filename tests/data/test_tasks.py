"""Task specs, named streams and the pure variant transforms."""

from __future__ import annotations

import numpy as np
import pytest

from hispo_pl.task_families import FAMILIES, VARIANTS
from hispo_pl.tasks import (
    DEFAULT_EPISODES,
    GRAMMAR,
    STREAMS,
    Task,
    TaskSpecError,
    parse_stream,
    parse_task,
    transform_action,
    transform_observation,
    untransform_action,
)

# --- parsing -----------------------------------------------------------------------------


def test_parse_full_spec():
    task = parse_task("pointmaze-umaze-PO[500]")
    assert (task.family, task.maze, task.variant, task.episodes) == (
        "pointmaze",
        "umaze",
        "PO",
        500,
    )
    assert task.env_id == "PointMaze_UMaze-v3"
    assert task.dataset_name == "pointmaze-umaze"


def test_parse_defaults():
    task = parse_task("pointmaze-umaze")
    assert task.variant == "N"
    assert task.episodes == 500 == DEFAULT_EPISODES
    assert task.spec == "pointmaze-umaze-N[500]"


@pytest.mark.parametrize(
    "spec, expected",
    [
        ("pointmaze-large-IA", ("pointmaze", "large", "IA", 500)),
        ("pointmaze-medium[37]", ("pointmaze", "medium", "N", 37)),
        ("antmaze-large-IA[100]", ("antmaze", "large", "IA", 100)),
        ("  antmaze-umaze-PA[1]  ", ("antmaze", "umaze", "PA", 1)),
    ],
)
def test_parse_variants_and_sizes(spec, expected):
    task = parse_task(spec)
    assert (task.family, task.maze, task.variant, task.episodes) == expected


@pytest.mark.parametrize("family", list(FAMILIES))
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_spec_round_trip(family, variant):
    if variant not in FAMILIES[family].variants:
        with pytest.raises(TaskSpecError, match="has no variant"):
            parse_task(f"{family}-{next(iter(FAMILIES[family].mazes))}-{variant}")
        return
    for maze in FAMILIES[family].mazes:
        task = Task(family, maze, variant, 123)
        assert parse_task(task.spec) == task
        assert parse_task(str(task)) == task
        assert parse_task(task) is task


def test_antmaze_env_id():
    assert parse_task("antmaze-medium").env_id == "AntMaze_Medium-v5"


@pytest.mark.parametrize(
    "spec, why",
    [
        ("humanoidmaze-umaze-N[10]", "unknown family"),
        ("pointmaze-huge-N[10]", "unknown maze"),
        ("pointmaze-umaze-XX[10]", "unknown variant"),
        ("pointmaze-umaze-N[0]", "episodes must be positive"),
        ("pointmaze-umaze[0]", "episodes must be positive"),
        ("pointmaze-umaze-N[-3]", "malformed"),
        ("pointmaze-umaze-po", "malformed"),
        ("pointmaze", "malformed"),
        ("", "malformed"),
        ("!!garbage!!", "malformed"),
        ("pointmaze-umaze-N[10]extra", "malformed"),
        ("pointmaze_umaze", "malformed"),
        ("amazeville-HXXO", "unknown maze"),
        ("amazeville-hxoo", "unknown maze"),
        ("simpletown-OXO-PO", "has no variant"),
        ("simpletown-Base", "malformed"),
    ],
)
def test_malformed_specs_raise_with_grammar(spec, why):
    with pytest.raises(TaskSpecError) as info:
        parse_task(spec)
    message = str(info.value)
    assert why in message
    assert GRAMMAR in message
    assert "<family>-<maze>[-<variant>][[<episodes>]]" in message
    assert isinstance(info.value, ValueError)


def test_grammar_lists_all_families_and_variants():
    for name in (*FAMILIES, *VARIANTS):
        assert name in GRAMMAR
    for family in ("amazeville", "simpletown"):
        for maze in FAMILIES[family].mazes:
            assert maze in GRAMMAR


def test_every_family_names_its_expert_and_kind():
    """Data generation, the env registry and drawing read these fields instead of names."""
    from hispo_pl.data.generation import expert_class

    experts = {f: expert_class(f"{f}-{next(iter(fam.mazes))}") for f, fam in FAMILIES.items()}
    assert {f: c.__name__ for f, c in experts.items()} == {
        "pointmaze": "PointMazeExpert",
        "antmaze": "AntMazeExpert",
        "amazeville": "GameExpert",
        "simpletown": "GameExpert",
    }
    assert all(hasattr(c, "act") and hasattr(c, "action_noise") for c in experts.values())
    assert [f for f, fam in FAMILIES.items() if fam.expert_reads_weights] == ["antmaze"]
    assert [f for f, fam in FAMILIES.items() if fam.game] == ["amazeville", "simpletown"]
    assert Task("amazeville", "HOOO").gym_id == "hispo_pl/AmazeVille_HOOO-v0"


def test_game_specs_default_to_the_papers_episode_counts():
    assert parse_task("amazeville-HXOO") == Task("amazeville", "HXOO", "N", 100)
    assert parse_task("simpletown-OXO") == Task("simpletown", "OXO", "N", 250)
    assert parse_task("simpletown-BASE[7]").episodes == 7
    assert parse_task("amazeville-LXOX").env_id == "hispo_pl/AmazeVille_LXOX-v0"


@pytest.mark.parametrize(
    "stream, mazes",
    [
        ("videogame-1", ["HOOO", "HXOO", "LOOO", "LOOX"]),
        ("videogame-2", ["LOOX", "HXOO", "HOOO", "LXOX"]),
        ("amazeville-1", ["HOOX", "HXOX", "HXOX", "HOOX"]),
        ("amazeville-2", ["LOOO", "LOOO", "LXOX", "LXOO"]),
        ("simpletown-1", ["BASE", "OXO", "BASE", "OOX"]),
        ("simpletown-2", ["BASE", "OXX", "XOO", "OXX"]),
    ],
)
def test_topological_streams(stream, mazes):
    tasks = parse_stream(stream)
    assert [t.maze for t in tasks] == mazes
    family = "simpletown" if stream.startswith("simpletown") else "amazeville"
    assert {t.family for t in tasks} == {family}
    assert {t.episodes for t in tasks} == {FAMILIES[family].default_episodes}


# --- streams -----------------------------------------------------------------------------


def _shape(stream: str) -> list[tuple[str, str]]:
    return [(t.maze, t.variant) for t in parse_stream(stream)]


def test_pointmaze_streams():
    assert _shape("pointmaze-1") == [
        ("umaze", "N"),
        ("large", "N"),
        ("umaze", "PO"),
        ("medium", "IO"),
    ]
    assert _shape("pointmaze-2") == [
        ("umaze", "PA"),
        ("medium", "PO"),
        ("medium", "N"),
        ("medium", "N"),
    ]
    assert STREAMS["pointmaze-1"] == [
        "pointmaze-umaze-N[500]",
        "pointmaze-large-N[500]",
        "pointmaze-umaze-PO[500]",
        "pointmaze-medium-IO[500]",
    ]
    assert all(t.family == "pointmaze" and t.episodes == 500 for t in parse_stream("pointmaze-2"))


@pytest.mark.parametrize("k", ["1", "2"])
def test_antmaze_streams_mirror_pointmaze(k):
    ant = parse_stream(f"antmaze-{k}")
    assert all(t.family == "antmaze" for t in ant)
    assert _shape(f"antmaze-{k}") == _shape(f"pointmaze-{k}")


def test_stream_registry_and_errors():
    assert set(STREAMS) == {
        *(
            f"{family}-{k}"
            for family in ("pointmaze", "antmaze", "amazeville", "simpletown")
            for k in "12"
        ),
        "videogame-1",
        "videogame-2",
    }
    with pytest.raises(TaskSpecError, match="known streams"):
        parse_stream("pointmaze-3")
    tasks = parse_stream(["pointmaze-umaze-IA[5]", "antmaze-large"])
    assert tasks == [Task("pointmaze", "umaze", "IA", 5), Task("antmaze", "large", "N", 500)]
    with pytest.raises(TaskSpecError):
        parse_stream(["pointmaze-umaze", "nope"])


# --- transforms --------------------------------------------------------------------------


@pytest.mark.parametrize("family", ["pointmaze", "antmaze"])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_untransform_inverts_transform(family, variant):
    task = Task(family, "umaze", variant)
    rng = np.random.default_rng(0)
    dim = FAMILIES[family].action_dim
    single = rng.uniform(-1, 1, dim)
    batch = rng.uniform(-1, 1, (7, dim))
    for a in (single, batch):
        t = transform_action(task, a)
        assert t.shape == a.shape
        np.testing.assert_array_equal(untransform_action(task, t), a)
        np.testing.assert_array_equal(transform_action(task, untransform_action(task, a)), a)
        if variant in ("N", "IO", "PO"):  # observation-only variants leave actions alone
            np.testing.assert_array_equal(t, a)
        else:
            assert not np.array_equal(t, a)


def test_pointmaze_action_transforms_exact():
    a = np.array([0.25, -0.75])
    np.testing.assert_array_equal(
        transform_action(parse_task("pointmaze-umaze-IA"), a), [-0.25, 0.75]
    )
    np.testing.assert_array_equal(
        transform_action(parse_task("pointmaze-umaze-PA"), a), [-0.75, 0.25]
    )
    np.testing.assert_array_equal(
        untransform_action(parse_task("pointmaze-umaze-PA"), a), [-0.75, 0.25]
    )


def test_antmaze_pa_shifts_one_leg():
    a = np.arange(8.0)
    task = parse_task("antmaze-umaze-PA")
    # one leg = two actuator entries: the last leg's pair moves to the front
    np.testing.assert_array_equal(transform_action(task, a), [6, 7, 0, 1, 2, 3, 4, 5])
    np.testing.assert_array_equal(untransform_action(task, a), [2, 3, 4, 5, 6, 7, 0, 1])
    np.testing.assert_array_equal(
        transform_action(parse_task("antmaze-umaze-IA"), a), [0, -1, -2, -3, -4, -5, -6, -7]
    )
    batch = np.stack([a, 10 + a])
    np.testing.assert_array_equal(
        transform_action(task, batch), [[6, 7, 0, 1, 2, 3, 4, 5], [16, 17, 10, 11, 12, 13, 14, 15]]
    )


@pytest.mark.parametrize("family", ["pointmaze", "antmaze"])
def test_observation_transforms(family):
    dim = FAMILIES[family].obs_dim
    obs = np.arange(1.0, dim + 1)
    task = lambda v: Task(family, "umaze", v)  # noqa: E731
    # PO is a cyclic shift by one feature: the last feature comes first
    np.testing.assert_array_equal(
        transform_observation(task("PO"), obs), np.concatenate([[float(dim)], np.arange(1.0, dim)])
    )
    np.testing.assert_array_equal(transform_observation(task("IO"), obs), -obs)
    for v in ("N", "IA", "PA"):
        np.testing.assert_array_equal(transform_observation(task(v), obs), obs)
    # batched: the shift is along the feature axis only
    batch = np.stack([obs, 100 + obs])
    out = transform_observation(task("PO"), batch)
    np.testing.assert_array_equal(out[1], transform_observation(task("PO"), 100 + obs))
    np.testing.assert_array_equal(out[:, 1:], batch[:, :-1])


def test_pointmaze_po_exact():
    obs = np.array([1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(
        transform_observation(parse_task("pointmaze-umaze-PO"), obs), [4.0, 1.0, 2.0, 3.0]
    )
