"""PNN: progressive columns with laterals on the HBC backbone."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
import torch
from helpers import fit_tiny_stream

from hispo_pl.config import BackboneConfig
from hispo_pl.metrics import module_bytes
from hispo_pl.modules import GoalConditionedBC, GrowingPolicy
from hispo_pl.modules.pnn import PNN
from hispo_pl.nn import fast
from hispo_pl.nn.hierarchy import HierarchicalPolicy, high_input_dim
from hispo_pl.nn.mlp import ResidualMLP, feature_dim
from hispo_pl.nn.progressive import (
    ProgressiveMLP,
    column_parameter_count,
    progressive_parameter_count,
)

ROOT = Path(__file__).resolve().parents[2]
STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]


def _module(kind: str = "hbc") -> PNN:
    return PNN(4, 2, backbone=BackboneConfig(kind=kind, high_hidden=8, low_hidden=16))


def _trainable(module: torch.nn.Module) -> set[str]:
    return {n for n, p in module.named_parameters() if p.requires_grad}


def _column_names(module: PNN, column: int) -> set[str]:
    """Parameter names of ``column`` and its laterals in both policies."""
    prefixes = [f"net.{p}.net.columns.{column}." for p in ("high", "low")]
    if column > 0:
        prefixes += [f"net.{p}.net.laterals.{column - 1}." for p in ("high", "low")]
    return {n for n, _ in module.named_parameters() if n.startswith(tuple(prefixes))}


def _nudge_trainable(module: torch.nn.Module, k: int) -> None:
    """Move every trainable weight (laterals included) as training would."""
    g = torch.Generator().manual_seed(100 + k)
    with torch.no_grad():
        for p in module.parameters():
            if p.requires_grad:
                p.add_(0.05 * torch.randn(p.shape, generator=g))


def _run_tasks(module: PNN, tasks: range) -> None:
    for k in tasks:
        module.task_index = k
        module.start_task(k)
        _nudge_trainable(module, k)
        module.finish_task(k)


def _obs(n=5):
    g = torch.Generator().manual_seed(0)
    return tuple(torch.randn(n, d, generator=g) for d in (4, 2, 2))


def _batch(n=32):
    g = torch.Generator().manual_seed(1)
    names = ("observation", "position", "goal", "subgoal", "action")
    dims = (4, 2, 2, 2, 2)
    return {k: torch.randn(n, d, generator=g) for k, d in zip(names, dims, strict=True)}


def _checkpoint(module: PNN, path: Path) -> Path:
    trainer = L.Trainer(logger=False, enable_checkpointing=False, accelerator="cpu")
    trainer.strategy.connect(module)
    trainer.save_checkpoint(path)
    return path


# --- the progressive network -----------------------------------------------------------------


def test_first_column_is_a_plain_residual_mlp():
    """Bit for bit, in one process: the same weights through the same kernels on the same
    shapes, and in training the same seeded masks."""
    net = ProgressiveMLP(7, 16, 3, dropout=0.1)
    plain = ResidualMLP(7, 16, 3, dropout=0.1)
    plain.load_state_dict(net.columns[0].state_dict())
    x = torch.randn(11, 7)
    net.eval(), plain.eval()
    assert torch.equal(net(x), plain(x))
    net.train(), plain.train()
    with fast.reference_path():  # plain modules both: the same masks, drawn in the same order
        torch.manual_seed(3)
        a = net(x)
        torch.manual_seed(3)
        assert torch.equal(a, plain(x))


def test_one_column_pnn_is_the_hbc_network():
    """Bit for bit, in one process: a single column runs the HBC network's kernels on its
    shapes."""
    m = _module().eval()
    hbc = HierarchicalPolicy(BackboneConfig(high_hidden=8, low_hidden=16), 4, 2).eval()
    hbc.high.net.load_state_dict(m.net.high.net.columns[0].state_dict())
    hbc.low.net.load_state_dict(m.net.low.net.columns[0].state_dict())
    obs, pos, goal = _obs()
    assert torch.equal(m.act(obs, pos, goal), hbc.act(obs, pos, goal))
    ours, theirs = m.losses(_batch()), hbc.losses(_batch())
    assert all(torch.equal(ours[k], theirs[k]) for k in theirs)


def test_flat_pnn_is_flat_bc_in_columns():
    """``kind="bc"``: one column is the flat BC network; columns grow, freeze and keep earlier
    tasks' actions as in the hierarchical PNN. Bit for bit, in one process: a single column
    runs flat BC's kernels on its shapes."""
    m = _module("bc").eval()
    flat = HierarchicalPolicy(BackboneConfig(kind="bc", low_hidden=16), 4, 2).eval()
    flat.policy.net.load_state_dict(m.net.policy.net.columns[0].state_dict())
    obs, pos, goal = _obs()
    assert torch.equal(m.act(obs, pos, goal), flat.act(obs, pos, goal))
    assert torch.equal(m.losses(_batch())["loss"], flat.losses(_batch())["loss"])
    assert m.reference_model().names == ("policy",)
    _run_tasks(m, range(1))
    m.eval()
    before = m.act(obs, pos, goal, task=0)
    _run_tasks(m, range(1, 3))
    m.eval()
    assert m.n_columns == 3 and torch.equal(m.act(obs, pos, goal, task=0), before)
    assert not torch.equal(m.act(obs, pos, goal, task=2), before)
    m.start_task(2)
    trainable = _trainable(m)
    assert trainable and all(
        n.startswith(("net.policy.net.columns.2.", "net.policy.net.laterals.1.")) for n in trainable
    )
    with pytest.raises(ValueError, match="unknown backbone"):
        _module("mlp")


def test_new_column_starts_independent_and_laterals_then_carry_earlier_features():
    torch.manual_seed(0)
    net = ProgressiveMLP(5, 16, 3, dropout=0.0)
    net.add_column()
    x = torch.randn(9, 5)
    alone = ResidualMLP(5, 16, 3, dropout=0.0)
    alone.load_state_dict(net.columns[1].state_dict())
    # zero laterals: column 1 is a plain network; column 0 does not change what it computes
    # (the plain network trains on the fast path: the same maths, fused kernels at one thread)
    torch.testing.assert_close(net(x), alone(x))
    with torch.no_grad():
        net.columns[0].head.weight.add_(1.0)
        net.columns[0].block[0].weight.add_(1.0)
    torch.testing.assert_close(net(x), alone(x))
    # non-zero laterals: column 0's features now flow into column 1, through every layer
    for name in ("block_first", "block_second", "head"):
        before = net(x)
        with torch.no_grad():
            getattr(net.laterals[0], name).weight.normal_(0.0, 0.1)
        assert not torch.allclose(net(x), before), name
    before = net(x)
    with torch.no_grad():
        net.columns[0].block[0].weight.add_(1.0)
    assert not torch.allclose(net(x), before)
    torch.testing.assert_close(net(x, column=0), net.columns[0](x))  # it reads no laterals


def test_zero_laterals_get_gradients_and_frozen_columns_get_none():
    m = _module()
    _run_tasks(m, range(1))
    m.start_task(1)
    m.train()
    m.losses(_batch())["loss"].backward()
    for policy in (m.net.high, m.net.low):
        for name in ("block_first", "block_second", "head"):
            grad = getattr(policy.net.laterals[0], name).weight.grad
            assert grad is not None and grad.abs().sum() > 0, name  # zeros do not stall
        assert all(p.grad is None for p in policy.net.columns[0].parameters())


# --- growth, freezing, acting ----------------------------------------------------------------


def test_implements_the_growing_policy_protocol():
    assert isinstance(_module(), GrowingPolicy)
    assert isinstance(_module().reference_model(), HierarchicalPolicy)


def test_start_task_adds_one_column_and_only_it_trains():
    m = _module()
    m.start_task(0)
    assert m.n_columns == 1 and _trainable(m) == _column_names(m, 0)
    m.finish_task(0)
    for k in (1, 2):
        m.start_task(k)
        m.start_task(k)  # idempotent: a second setup of the same task does not grow again
        assert m.n_columns == k + 1
        assert _trainable(m) == _column_names(m, k)
        assert len(m.net.high.net.laterals[k - 1].head.weight.T) == k * 8  # from every earlier
        m.finish_task(k)
    assert m.task_column.tolist() == [0, 1, 2]
    with pytest.raises(ValueError, match="in stream order"):
        m.start_task(4)
    with pytest.raises(ValueError, match="only its newest column"):
        m.start_task(1)


def test_adding_columns_leaves_earlier_tasks_actions_bit_identical():
    m = _module()
    _run_tasks(m, range(2))
    m.eval()
    obs, pos, goal = _obs()
    before = [m.act(obs, pos, goal, task=k) for k in range(2)]
    _run_tasks(m, range(2, 4))
    m.eval()
    assert m.n_columns == 4
    for k in range(2):
        assert torch.equal(m.act(obs, pos, goal, task=k), before[k])
    actions = [m.act(obs, pos, goal, task=k) for k in range(4)]
    assert not torch.equal(actions[3], actions[1])  # each task has its own column
    assert torch.equal(m.act(obs, pos, goal, task=9), actions[3])  # unseen: the newest
    m.task_index = 2
    assert torch.equal(m.act(obs, pos, goal), actions[2])  # default: the current task


def test_stored_size_grows_with_the_laterals():
    """MEM after 4 tasks at the paper's widths: 4 columns + 6 lateral sets per policy."""
    m = PNN(4, 2, backbone=BackboneConfig())  # PointMaze: obs 4, action 2; 64 high / 256 low
    unit = module_bytes(m.reference_model())
    sizes = []
    for k in range(4):
        m.start_task(k)
        m.finish_task(k)
        sizes.append(module_bytes(m))
    f = feature_dim(2)
    high, low = (f + 4 + 4, 64, 2), (f + 4, 256, 2)  # (in, hidden, out): fixed log-stds
    assert unit == 4 * (column_parameter_count(*high) + column_parameter_count(*low))
    expected = [
        4 * (progressive_parameter_count(n, *high) + progressive_parameter_count(n, *low)) + 8 * n
        for n in range(1, 5)
    ]  # float32 weights + one int64 task entry per finished task
    assert sizes == expected
    steps = [b - a for a, b in zip(sizes, sizes[1:], strict=False)]
    assert steps[0] < steps[1] < steps[2]  # superlinear: each column brings more laterals
    mem = sizes[-1] / unit
    print(f"PNN MEM after 4 tasks: {mem:.4f} single-task HBCs ({sizes[-1]} / {unit} bytes)")
    assert mem == pytest.approx(9.7525, abs=1e-4)


# --- checkpoints -----------------------------------------------------------------------------


def test_checkpoint_alone_acts_identically_on_every_task(tmp_path):
    """Bit for bit, in one process: the restored module runs the saved weights through the same
    kernels on the same shapes as the original."""
    m = _module()
    _run_tasks(m, range(3))
    m.eval()
    path = _checkpoint(m, tmp_path / "m.ckpt")
    restored = GoalConditionedBC.from_checkpoint_file(str(path))
    assert isinstance(restored, PNN) and restored.n_columns == 3
    assert restored.task_column.tolist() == [0, 1, 2]
    obs, pos, goal = _obs()
    for k in range(3):
        assert torch.equal(restored.act(obs, pos, goal, task=k), m.act(obs, pos, goal, task=k))


def test_flat_pnn_checkpoint_restores_its_columns(tmp_path):
    """Bit for bit, in one process: the restored module runs the saved weights through the same
    kernels on the same shapes as the original."""
    m = _module("bc")
    _run_tasks(m, range(3))
    m.eval()
    restored = GoalConditionedBC.from_checkpoint_file(str(_checkpoint(m, tmp_path / "m.ckpt")))
    assert isinstance(restored, PNN) and restored.n_columns == 3
    obs, pos, goal = _obs()
    for k in range(3):
        assert torch.equal(restored.act(obs, pos, goal, task=k), m.act(obs, pos, goal, task=k))


def test_resume_from_a_checkpoint_adds_one_column_and_freezes_the_rest(tmp_path):
    """Bit for bit, in one process: the restored module runs the saved weights through the same
    kernels on the same shapes as the original."""
    m = _module()
    _run_tasks(m, range(2))
    path = _checkpoint(m, tmp_path / "task_02.ckpt")
    resumed = _module()
    resumed.load_checkpoint_file(path)  # as the ContinualLoop does on a rerun
    resumed.task_index = 2
    resumed.start_task(2)
    assert resumed.n_columns == 3 and _trainable(resumed) == _column_names(resumed, 2)
    m.eval(), resumed.eval()
    obs, pos, goal = _obs()
    for k in range(2):
        assert torch.equal(resumed.act(obs, pos, goal, task=k), m.act(obs, pos, goal, task=k))


# --- end to end through hispo-pl fit ---------------------------------------------------------


def _fit(method: str, save_dir: Path) -> dict:
    return fit_tiny_stream(method, save_dir)[0]


def test_stream_end_to_end(tiny_umaze, tmp_path):
    results = _fit("pnn", tmp_path)
    assert len(results["R"]) == 2
    assert results["R"][1][0] == results["R"][0][0] and results["BWT"] == 0.0
    run_dir = tmp_path / "pointmaze-1" / "seed0"
    first = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_01.ckpt"))
    second = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    assert isinstance(second, PNN) and (first.n_columns, second.n_columns) == (1, 2)
    assert second.task_column.tolist() == [0, 1]
    # task 1's column is kept as it was; task 2 trained a new column and its laterals
    old, new = first.state_dict(), second.state_dict()
    assert all(torch.equal(old[k], new[k]) for k in old if k != "task_column")
    assert any(p.abs().sum() > 0 for p in second.net.low.net.laterals[0].parameters())
    # MEM: two columns and one lateral set per policy, in units of one HBC
    hp, net = second, second.backbone_config
    assert net.high_log_std == 0.0  # the method config fixes it: high head = goal_dim outputs
    assert net.low_log_std == 0.0 and not net.low_obs and net.low_velocity  # goal-space low
    f = feature_dim(hp.goal_dim)
    high = (high_input_dim(hp.obs_dim, hp.goal_dim, net.high_obs), net.high_hidden, hp.goal_dim)
    low = (f + hp.goal_dim, net.low_hidden, hp.action_dim)
    unit = column_parameter_count(*high) + column_parameter_count(*low)
    pair = progressive_parameter_count(2, *high) + progressive_parameter_count(2, *low)
    assert results["MEM"] > 2
    assert results["MEM"] == pytest.approx(pair / unit, rel=1e-3)  # + the task map


def test_flat_stream_end_to_end(tiny_umaze, tmp_path):
    results = _fit("bc-pnn", tmp_path)
    assert results["BWT"] == 0.0 and results["R"][1][0] == results["R"][0][0]
    second = GoalConditionedBC.from_checkpoint_file(
        str(tmp_path / "pointmaze-1" / "seed0" / "task_02.ckpt")
    )
    assert isinstance(second, PNN) and second.n_columns == 2
    hp = second
    assert hp.backbone_config.high_obs is True  # PointMaze: the flat policy reads the observation
    shape = (
        high_input_dim(hp.obs_dim, hp.goal_dim, hp.backbone_config.high_obs),
        hp.backbone_config.low_hidden,
        2 * hp.action_dim,
    )
    # MEM's unit is one flat BC network: two columns and one lateral set of it
    expected = progressive_parameter_count(2, *shape) / column_parameter_count(*shape)
    assert results["MEM"] == pytest.approx(expected, rel=1e-3)
