"""Environment families: each names a behaviour that implements the family protocol, and
evaluation's reset options are the ones the family drew before the protocol existed."""

from __future__ import annotations

import numpy as np
import pytest

from hispo_pl.envs import make_env
from hispo_pl.envs.family import FamilyBehaviour, family_behaviour
from hispo_pl.evaluation import reset_options
from hispo_pl.task_families import FAMILIES
from hispo_pl.tasks import parse_task


@pytest.mark.parametrize("family", FAMILIES)
def test_each_family_resolves_to_a_behaviour(family):
    assert isinstance(family_behaviour(FAMILIES[family]), FamilyBehaviour)


@pytest.mark.parametrize(
    "task, expected",
    [
        (
            "pointmaze-umaze",
            [
                {"reset_cell": [3, 2], "goal_cell": [3, 1]},
                {"reset_cell": [1, 3], "goal_cell": [1, 2]},
                {"reset_cell": [3, 3], "goal_cell": [1, 1]},
            ],
        ),
        (
            "amazeville-HOOO",
            [
                {"start": [55.0, 3.0], "goal": [35.0, 47.0]},
                {"start": [31.0, 3.0], "goal": [13.0, 41.0]},
                {"start": [5.0, 3.0], "goal": [5.0, 41.0]},
            ],
        ),
    ],
)
def test_reset_options_are_unchanged_for_a_fixed_seed(task, expected):
    env = make_env(task)
    try:
        options = reset_options(parse_task(task), env, 3, seed=0)
    finally:
        env.close()
    assert [{k: np.asarray(v).tolist() for k, v in o.items()} for o in options] == expected
