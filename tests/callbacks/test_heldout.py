"""Decisions on held-out data: episodes split off a task are never trained on, the search
scores on them, and every decision records its train and held-out losses and how much the new
anchor was still improving (the convergence diagnostic)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from helpers import quiet_trainer

from hispo_pl.callbacks import AnchorExtension, DirichletEvaluation, SubspacePruning
from hispo_pl.callbacks.loss_search import window_start
from hispo_pl.config import BackboneConfig, OptimConfig
from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.data.datasets import EpisodeArrays
from hispo_pl.data.sampler import HERConfig, HERSampler
from hispo_pl.decisions import decided_by_budget
from hispo_pl.modules.hispo import HiSPO


def _episodes(lengths: list[int]) -> EpisodeArrays:
    """Episodes whose rows carry their episode number as observation, position and action."""
    obs, end, idx = [], [], []
    start = 0
    for k, n in enumerate(lengths):
        obs.append(np.full((n + 1, 2), k, dtype=np.float32))
        end.append(np.full(n + 1, start + n, dtype=np.int64))
        idx.append(np.arange(start, start + n, dtype=np.int64))
        start += n + 1
    o, e = np.concatenate(obs), np.concatenate(end)
    return EpisodeArrays(o, o.copy(), o.copy(), e, np.concatenate(idx), e.copy())


def test_split_is_by_episode_disjoint_and_complete():
    data = _episodes([30 + k for k in range(20)])
    train, held = data.split_episodes(0.1, seed=3)
    assert (train.n_episodes, held.n_episodes) == (18, 2)
    assert not set(train.sample_index) & set(held.sample_index)
    assert sorted([*train.sample_index, *held.sample_index]) == sorted(data.sample_index)
    ep_of = data.episode_end
    held_eps = set(ep_of[held.sample_index])
    assert not held_eps & set(ep_of[train.sample_index])
    assert data.split_episodes(0.1, seed=3)[1].sample_index.tolist() == held.sample_index.tolist()


def test_no_holdout_scores_on_the_training_data_and_tiny_data_keeps_one_episode_each():
    data = _episodes([10, 10, 10])
    train, held = data.split_episodes(0.0)
    assert train is data and held is data
    train, held = data.split_episodes(0.1)  # 0.3 episodes rounds to 0: still one held out
    assert (train.n_episodes, held.n_episodes) == (2, 1)
    with pytest.raises(ValueError, match=r"\[0, 1\)"):
        data.split_episodes(1.0)


def test_relabelled_goals_and_subgoals_never_leave_the_training_episodes():
    data = _episodes([40] * 10)
    train, _ = data.split_episodes(0.3, seed=0)
    allowed = set(np.unique(data.observations[train.sample_index, 0]).tolist())
    batch = HERSampler(train, HERConfig(waysteps=5, temperature=50.0), 4096, seed=0).sample()
    for key in ("observation", "goal", "subgoal", "action"):
        assert set(np.unique(batch[key][:, 0].numpy()).tolist()) <= allowed


def test_datamodule_trains_on_train_and_scores_on_heldout_episodes(tiny_umaze):
    dm = TaskDataModule("pointmaze-umaze-N[3]", batch_size=64, steps_per_epoch=2, holdout=0.1)
    dm.setup("fit")
    train_rows = set(dm.splits["train"].sample_index.tolist())
    held_rows = set(dm.splits["heldout"].sample_index.tolist())
    assert train_rows and held_rows and not train_rows & held_rows
    held_obs = torch.from_numpy(dm.data.observations[sorted(held_rows)])
    train_obs = torch.from_numpy(dm.data.observations[sorted(train_rows)])
    scored = dm.fixed_batches(1, seed=0)[0]["observation"]
    trained = next(iter(dm.train_dataloader()))["observation"]
    # every row drawn is a row of its own split (observations of a continuous maze are unique)
    assert all((held_obs == row).all(-1).any() for row in scored[:32])
    assert all((train_obs == row).all(-1).any() for row in trained[:32])
    with pytest.raises(ValueError, match="holdout"):
        TaskDataModule("pointmaze-umaze-N[3]", holdout=1.5)


def test_window_start_and_the_budget_rule():
    assert window_start(100, 0.2) == 80
    assert window_start(3, 0.2) == 2  # at least one step inside the window
    assert window_start(-1, 0.2) is None and window_start(100, 0.0) is None
    assert decided_by_budget(0.3, eps=0.1) and not decided_by_budget(0.05, eps=0.1)
    assert not decided_by_budget(None, eps=0.0)


def test_decisions_record_heldout_and_train_losses_and_warn_when_decided_by_budget(
    tiny_umaze, tmp_path
):
    stream = ["pointmaze-umaze-N[3]", "pointmaze-umaze-IA[3]"]
    torch.manual_seed(0)
    backbone, optim = BackboneConfig(high_hidden=8, low_hidden=16), OptimConfig(lr=3e-3)
    module = HiSPO(obs_dim=4, action_dim=2, backbone=backbone, optim=optim)
    search = DirichletEvaluation(n_candidates=16, n_batches=2, convergence_window=0.5)
    for task in range(2):
        module.task_index = task
        trainer = quiet_trainer(
            max_steps=20,
            default_root_dir=tmp_path,
            callbacks=[AnchorExtension(), search, SubspacePruning(eps_high=0.0, eps_low=0.0)],
        )
        dm = TaskDataModule(stream[task], batch_size=64, steps_per_epoch=20, stream=stream)
        if task == 1:  # a freshly started anchor still improves by far more than eps = 0
            with pytest.warns(UserWarning, match="step budget, not the task"):
                trainer.fit(module, datamodule=dm)
        else:
            trainer.fit(module, datamodule=dm)
    records = [json.loads(x) for x in (tmp_path / "decisions.jsonl").read_text().splitlines()]
    assert [r["task"] for r in records] == [0, 0, 1, 1]
    for r in records:
        assert r["l_curr_train"] > 0 and r["l_window"] > 0
        assert r["improvement"] == pytest.approx(r["l_window"] / r["l_curr"] - 1.0)
    for r in records[2:]:
        assert r["l_prev"] > 0 and r["l_prev_train"] > 0
    # the decision's L_curr is scored on held-out episodes: it differs from the train loss
    assert all(r["l_curr"] != r["l_curr_train"] for r in records)
