"""The per-task-network baselines (SC1, SCN, FT1, FTN, FRZ) and their flat-BC versions."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from helpers import fit_tiny_stream

from hispo_pl.callbacks.networks import trains_on
from hispo_pl.config import BackboneConfig
from hispo_pl.metrics import module_bytes
from hispo_pl.modules import GoalConditionedBC, NetworkPerTask

ROOT = Path(__file__).resolve().parents[2]
STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]


def _module(init="fresh", keep="all", backbone="hbc") -> NetworkPerTask:
    config = BackboneConfig(kind=backbone, high_hidden=8, low_hidden=16)
    return NetworkPerTask(4, 2, backbone=config, init=init, keep=keep)


def _trainable(module) -> set[str]:
    return {n for n, p in module.named_parameters() if p.requires_grad}


def _states_equal(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


def _run_tasks(module: NetworkPerTask, n: int) -> None:
    """Start and finish ``n`` tasks, nudging the trainable weights in each as training would."""
    for k in range(n):
        module.task_index = k
        module.start_task(k)
        with torch.no_grad():
            for p in module.parameters():
                if p.requires_grad:
                    p.add_(0.01 * (k + 1))
        module.finish_task(k)


def _obs(n=5):
    g = torch.Generator().manual_seed(0)
    return tuple(torch.randn(n, d, generator=g) for d in (4, 2, 2))


def test_trains_on_first_only_for_frz():
    assert [trains_on(k, "all") for k in range(3)] == [True, True, True]
    assert [trains_on(k, "first") for k in range(3)] == [True, False, False]


@pytest.mark.parametrize("keep,expected_nets", [("all", 3), ("last", 1)])
@pytest.mark.parametrize("init", ["fresh", "previous"])
def test_start_task_grows_or_replaces_and_only_the_newest_trains(init, keep, expected_nets):
    m = _module(init, keep)
    m.start_task(0)
    m.finish_task(0)
    first = [p.detach().clone() for p in m.nets[-1].parameters()]
    m.start_task(1)
    new = list(m.nets[-1].parameters())
    same = all(torch.equal(a, b) for a, b in zip(first, new, strict=True))
    assert same == (init == "previous")  # a copy of the previous network, or a fresh one
    assert _trainable(m) == {
        n for n, _ in m.named_parameters() if n.startswith(f"nets.{len(m.nets) - 1}.")
    }
    m.start_task(1)  # idempotent: a second setup of the same task does not grow again
    m.finish_task(1)
    m.start_task(2)
    m.finish_task(2)
    assert len(m.nets) == expected_nets
    expected_map = [0, 1, 2] if keep == "all" else [0, 0, 0]
    assert m.task_network.tolist() == expected_map


def test_each_task_acts_with_its_own_network_when_all_are_kept():
    m = _module("previous", "all")
    _run_tasks(m, 3)
    m.eval()  # deterministic: no dropout
    obs, pos, goal = _obs()
    actions = [m.act(obs, pos, goal, task=k) for k in range(3)]
    for k in range(3):
        assert torch.equal(actions[k], m.nets[k].act(obs, pos, goal))
    assert not torch.equal(actions[0], actions[2])  # fine-tuned copies differ
    # an unseen task acts with the newest network
    assert torch.equal(m.act(obs, pos, goal, task=5), actions[2])


def test_checkpoint_alone_restores_every_tasks_policy(tmp_path):
    """Bit for bit, in one process: the restored module runs the saved weights through the same
    kernels on the same shapes as the original."""
    import lightning as L

    m = _module("fresh", "all")
    _run_tasks(m, 3)
    m.eval()
    trainer = L.Trainer(logger=False, enable_checkpointing=False, accelerator="cpu")
    trainer.strategy.connect(m)
    path = tmp_path / "m.ckpt"
    trainer.save_checkpoint(path)
    restored = GoalConditionedBC.from_checkpoint_file(str(path))
    assert isinstance(restored, NetworkPerTask) and len(restored.nets) == 3
    obs, pos, goal = _obs()
    for k in range(3):
        assert torch.equal(restored.act(obs, pos, goal, task=k), m.act(obs, pos, goal, task=k))


def test_reference_model_is_one_backbone_network():
    hbc, bc = _module(backbone="hbc"), _module(backbone="bc")
    assert hbc.reference_model().names == ("high", "low")
    assert bc.reference_model().names == ("policy",)
    assert module_bytes(hbc.reference_model()) == module_bytes(hbc.nets[0])
    with pytest.raises(ValueError, match="init must be"):
        NetworkPerTask(4, 2, init="copy")


# --- end to end through hispo-pl fit ---------------------------------------------------------


def _fit(method: str, save_dir: Path) -> dict:
    return fit_tiny_stream(method, save_dir)[0]


# MEM after two tasks: the networks kept, in units of one network
EXPECTED_MEM = {"sc1": 1, "scn": 2, "ft1": 1, "ftn": 2, "frz": 1}


@pytest.mark.parametrize("method", sorted(EXPECTED_MEM))
def test_stream_end_to_end(method, tiny_umaze, tmp_path):
    results = _fit(method, tmp_path)
    assert len(results["R"]) == 2
    assert results["MEM"] == pytest.approx(EXPECTED_MEM[method], rel=1e-3)  # + the task map
    if method in ("scn", "ftn", "frz"):  # what task 1 acts with is untouched by task 2
        assert results["R"][1][0] == results["R"][0][0] and results["BWT"] == 0.0
    run_dir = tmp_path / "pointmaze-1" / "seed0"
    first = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_01.ckpt"))
    second = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    if method == "frz":  # nothing trained on task 2
        assert _states_equal(first.nets[0], second.nets[0])
        assert results["R"][1] == results["R"][0]
    else:
        assert not _states_equal(first.nets[0], second.nets[-1])
    if method in ("scn", "ftn"):  # the first task's network is kept as it was
        assert _states_equal(first.nets[0], second.nets[0])


def test_flat_bc_version_runs_on_the_same_loop(tiny_umaze, tmp_path):
    results = _fit("bc-ftn", tmp_path)
    run_dir = tmp_path / "pointmaze-1" / "seed0"
    module = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    assert all(net.names == ("policy",) for net in module.nets) and len(module.nets) == 2
    assert results["MEM"] == pytest.approx(2, rel=1e-3) and results["BWT"] == 0.0


# --- replay (RPL) ----------------------------------------------------------------------------


def test_split_evenly_and_mixed_batches(tiny_umaze):
    from hispo_pl.data.sampler import HERConfig, HERSampler, MixedSampler, split_evenly

    assert split_evenly(10, 3) == [4, 3, 3] and sum(split_evenly(1024, 3)) == 1024
    her = HERConfig(waysteps=5, temperature=10.0)
    first, second = HERSampler(tiny_umaze, her, seed=0), HERSampler(tiny_umaze, her, seed=1)
    batch = MixedSampler([first, second], batch_size=7).sample()
    assert all(len(v) == 7 for v in batch.values())
    # the first share is exactly what the first sampler draws alone with the same seed
    alone = HERSampler(tiny_umaze, her, seed=0).sample(4)
    assert torch.equal(batch["observation"][:4], alone["observation"])


def test_replay_datamodule_draws_from_every_earlier_task(tiny_umaze):
    from hispo_pl.data.datamodule import TaskDataModule

    stream = [
        "pointmaze-umaze-PA[3]",
        "pointmaze-umaze-N[3]",
        "pointmaze-umaze-PO[3]",
        "pointmaze-umaze-N[3]",
    ]
    dm = TaskDataModule(task="pointmaze-umaze-N[3]", stream=stream, replay=True, batch_size=8)
    assert [t.spec for t in dm.earlier_tasks()] == ["pointmaze-umaze-PA[3]"]
    dm = TaskDataModule(task="pointmaze-umaze-PO[3]", stream=stream, replay=True, batch_size=9)
    dm.setup("fit")
    assert [t.spec for t in dm.earlier_tasks()] == ["pointmaze-umaze-PA[3]", "pointmaze-umaze-N[3]"]
    batch = next(iter(dm.train_dataloader()))
    assert len(batch["action"]) == 9
    assert len(dm.replayed) == 2
    assert dm.fixed_batches(1, seed=0)[0]["action"].shape == (9, 2)  # current task only
    with pytest.raises(ValueError, match="not in the stream"):
        TaskDataModule(task="pointmaze-umaze-IA[3]", stream=stream, replay=True).earlier_tasks()


def test_replay_stream_end_to_end(tiny_umaze, tmp_path):
    results = _fit("rpl", tmp_path)
    assert len(results["R"]) == 2 and results["MEM"] == pytest.approx(1, rel=1e-3)
