"""HiSPO's callbacks in real (short) Lightning fits: extension before the optimiser, the
Dirichlet search of the previous subspace, keep/prune decisions, order checks and the
stream evaluation row."""

from __future__ import annotations

from types import SimpleNamespace

import lightning as L
import numpy as np
import pytest
import torch
from helpers import quiet_trainer, tiny_hispo
from lightning.pytorch.loggers import Logger

import hispo_pl.callbacks.anchors as subspace_callbacks
from hispo_pl.callbacks import (
    AnchorExtension,
    DirichletEvaluation,
    RolloutEvaluation,
    SubspacePruning,
)
from hispo_pl.config import BackboneConfig
from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.modules.hbc import HBC
from hispo_pl.modules.hispo import SUBSPACES, HiSPO
from hispo_pl.results import LossDecision, SearchResult
from hispo_pl.rundir import RunDir
from hispo_pl.tasks import parse_task

STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-IA[3]", "pointmaze-umaze-PO[3]"]
SIZES = {"obs_dim": 4, "action_dim": 2, "backbone": BackboneConfig(high_hidden=8, low_hidden=16)}


class RecordOptimizer(L.Callback):
    """Remembers which parameters the optimiser of the fit received."""

    def __init__(self):
        self.params: list[torch.nn.Parameter] = []
        self.newest: set[int] = set()

    def on_train_start(self, trainer, pl_module):
        self.params = [p for g in trainer.optimizers[0].param_groups for p in g["params"]]
        self.newest = {
            id(p)
            for n, p in pl_module.named_parameters()
            if (n.startswith("policies") and n.endswith(f".{pl_module.task_index}"))
            or n.startswith("scores")
        }


def _callbacks(eps: float = 0.1, episodes: int = 2) -> list[L.Callback]:
    return [
        AnchorExtension(),
        DirichletEvaluation(n_candidates=32, n_batches=2),
        SubspacePruning(eps_high=eps, eps_low=eps),
        RolloutEvaluation(episodes=episodes),
    ]


def _fit(module, task_index: int, root, callbacks, stream=STREAM) -> L.Trainer:
    module.task_index = task_index
    trainer = quiet_trainer(
        max_steps=5,
        default_root_dir=root,
        callbacks=callbacks,
    )
    dm = TaskDataModule(stream[task_index], batch_size=64, steps_per_epoch=5, stream=stream)
    trainer.fit(module, datamodule=dm)
    return trainer


def _fresh_module(seed: int = 0) -> HiSPO:
    L.seed_everything(seed, verbose=False)
    return HiSPO(**SIZES)


@pytest.fixture(scope="module")
def first_task(tiny_umaze, tmp_path_factory):
    """Task 0 of the stream, trained once: its run dir, callbacks, module and checkpoint."""
    root = tmp_path_factory.mktemp("task0")
    module = _fresh_module()
    callbacks = _callbacks()
    trainer = _fit(module, 0, root, callbacks)
    ckpt = root / "task_01.ckpt"
    trainer.save_checkpoint(ckpt)
    return {"root": root, "callbacks": callbacks, "module": module, "ckpt": ckpt}


def _after_first_task() -> HiSPO:
    return _fresh_module(seed=1)  # weights replaced by the checkpoint


# --- task 0 -------------------------------------------------------------------------------------


def test_first_task_stores_the_single_anchor(first_task):
    module, root = first_task["module"], first_task["root"]
    for name in SUBSPACES:
        assert module.n_anchors(name) == 1
        assert module.task_alphas(name).tolist() == [[1.0]]
    assert not any(p.requires_grad for p in module.parameters())  # frozen after the task
    decisions = RunDir(root).decisions()
    assert [(d.task, d.subspace, d.decision) for d in decisions] == [
        (0, "high", "first"),
        (0, "low", "first"),
    ]
    for d in decisions:
        assert d.anchors == 1 and d.l_prev is None and d.alpha_curr == [1.0]
        assert d.l_curr >= 0
    assert not (root / "search").exists()  # one anchor: nothing to search


def test_stream_evaluation_row_covers_the_whole_stream(first_task):
    rollout, record = first_task["callbacks"][-1], first_task["module"].task_record
    assert isinstance(rollout, RolloutEvaluation)
    row = record.success_row  # what the loop reads
    assert row is not None and len(row) == len(STREAM)
    assert all(0.0 <= s <= 1.0 for s in row)
    assert all(s * rollout.episodes == round(s * rollout.episodes) for s in row)  # k/episodes
    assert record.evaluation["success"] == row[0] and record.episodes == rollout.episodes
    # one evaluator (and its environments) per task of the stream, kept for the next tasks
    assert {t.spec for t in rollout._evaluators} == set(STREAM)


# --- task 1: extension, search, pruning -------------------------------------------------------


def test_extension_happens_before_the_optimiser_and_a_huge_eps_prunes(first_task, tmp_path):
    module = _after_first_task()
    module.load_checkpoint_file(first_task["ckpt"])
    old_params = list(module.parameters())  # kept alive: a freed object's id can be reused
    old = {id(p) for p in old_params}
    recorder = RecordOptimizer()
    _fit(module, 1, tmp_path, [*_callbacks(eps=1e9), recorder])

    optimised = {id(p) for p in recorder.params}
    assert optimised, "the optimiser received no parameters"
    assert optimised == recorder.newest  # the anchors added for task 1, and the new scores
    assert not optimised & old  # no anchor of task 0 (nor its scores) is trained
    # the optimiser held exactly the newest anchor of every layer and the new scores; pruning
    # dropped those anchors afterwards, so they are no longer in the module
    n_layer_params = sum(1 for n, _ in module.named_parameters() if n.startswith("policies"))
    assert len(optimised) == n_layer_params + len(SUBSPACES)

    for name in SUBSPACES:
        assert module.n_anchors(name) == 1
        assert module.task_alphas(name).tolist() == [[1.0], [1.0]]
    decisions = RunDir(tmp_path).decisions()
    assert [(d.task, d.decision, d.anchors) for d in decisions] == [
        (1, "prune", 1),
        (1, "prune", 1),
    ]
    for d in decisions:
        assert d.alpha_prev == [1.0, 0.0] and len(d.alpha_curr) == 2
        assert d.eps == 1e9
    for name in SUBSPACES:  # two anchors: the previous subspace is the single point [1, 0]
        with np.load(tmp_path / "search" / f"task_02_{name}.npz") as f:
            assert f["alphas"].tolist() == [[1.0, 0.0]]
            assert f["losses"].shape == (1,) and f["losses"][0] >= 0
            assert float(f["l_curr"]) == pytest.approx(
                next(d.l_curr for d in decisions if d.subspace == name)
            )


def test_extension_trains_only_the_newest_anchor(first_task, tmp_path):
    """While task 1 trains, the anchors of task 0 do not move; the new one does."""
    module = _after_first_task()
    module.load_checkpoint_file(first_task["ckpt"])
    before = {k: v.clone() for k, v in module.state_dict().items() if k.startswith("policies")}
    _fit(module, 1, tmp_path, [AnchorExtension()])  # no search/pruning: keep both anchors
    for name in SUBSPACES:
        assert module.n_anchors(name) == 2
    after = module.state_dict()
    for k, v in before.items():
        assert torch.equal(after[k], v), k  # anchor 0 frozen
    moved = [k for k in after if k.startswith("policies") and k.endswith(".1")]
    assert any(not torch.equal(after[k], after[k[:-1] + "0"]) for k in moved)


@pytest.mark.parametrize(
    ("task", "anchor_init", "starts_at_mean"),
    [
        ("pointmaze-umaze-N", None, True),  # the family's: mean
        ("amazeville-HXOO", None, False),  # the game mazes': random
        ("amazeville-HXOO", "mean", True),  # the method config's wins
    ],
)
def test_anchor_extension_starts_the_anchor_as_the_family_says(task, anchor_init, starts_at_mean):
    module = tiny_hispo(anchor_init=anchor_init)
    module.task_index = 1
    trainer = SimpleNamespace(datamodule=SimpleNamespace(task=parse_task(task)))
    AnchorExtension().setup(trainer, module, "fit")
    for name in SUBSPACES:
        net = module._nets(name)[0]
        first, new = net.head.weights[0], net.head.weights[1]
        assert torch.equal(first, new) is starts_at_mean  # one old anchor: its mean is itself


def test_anchor_extension_adds_once_per_task(first_task, tmp_path):
    module = _after_first_task()
    module.load_checkpoint_file(first_task["ckpt"])
    module.task_index = 1
    trainer = L.Trainer(logger=False, callbacks=[AnchorExtension()], default_root_dir=tmp_path)
    ext = trainer.callbacks[0]
    ext.setup(trainer, module, "fit")
    ext.setup(trainer, module, "fit")  # e.g. a second fit of the same task
    assert [module.n_anchors(n) for n in SUBSPACES] == [2, 2]
    ext.setup(trainer, module, "validate")
    assert [module.n_anchors(n) for n in SUBSPACES] == [2, 2]
    # task 3 after pruning elsewhere: fewer anchors than tasks, still one extension per task
    module.task_index = 3
    ext.setup(trainer, module, "fit")
    ext.setup(trainer, module, "fit")
    assert [module.n_anchors(n) for n in SUBSPACES] == [3, 3]


def test_kept_anchors_grow_the_search_to_the_previous_simplex(first_task, tmp_path, monkeypatch):
    monkeypatch.setattr(subspace_callbacks, "keep_previous", lambda *args: False)
    module = _after_first_task()
    module.load_checkpoint_file(first_task["ckpt"])
    for k in (1, 2):
        _fit(module, k, tmp_path, _callbacks())
    for name in SUBSPACES:
        assert module.n_anchors(name) == 3
        rows = module.task_alphas(name)
        assert rows.shape == (3, 3)
        assert rows[0].tolist() == [1.0, 0.0, 0.0]
        assert rows[1, 2] == 0  # task 1 never uses the anchor of task 2
        torch.testing.assert_close(rows.sum(1), torch.ones(3))
        with np.load(tmp_path / "search" / f"task_03_{name}.npz") as f:
            alphas, losses = f["alphas"], f["losses"]
        assert alphas.shape == (32, 3) and losses.shape == (32,)
        assert np.all(alphas[:, 2] == 0)
        np.testing.assert_allclose(alphas.sum(1), 1.0, rtol=1e-6)
        assert np.all(losses >= 0) and np.all(np.isfinite(losses))
    decisions = RunDir(tmp_path).decisions()
    assert [d.decision for d in decisions] == ["keep"] * 4
    assert [d.anchors for d in decisions] == [2, 2, 3, 3]
    for d in decisions[2:]:  # the best candidate is the one reported
        with np.load(tmp_path / "search" / f"task_03_{d.subspace}.npz") as f:
            best = int(np.argmin(f["losses"]))
            assert d.l_prev == pytest.approx(float(f["losses"][best]))
            np.testing.assert_allclose(d.alpha_prev, f["alphas"][best])


def test_a_repeated_task_finds_its_own_point_among_the_stored_ones(
    first_task, tmp_path, monkeypatch
):
    monkeypatch.setattr(subspace_callbacks, "keep_previous", lambda *args: False)
    repeat = [STREAM[0], STREAM[1], STREAM[0]]  # task 2 is task 0 again
    callbacks = _callbacks()
    callbacks[1] = DirichletEvaluation(n_candidates=32, n_batches=2, stored_points=True)
    module = _after_first_task()
    module.load_checkpoint_file(first_task["ckpt"])
    for k in (1, 2):
        _fit(module, k, tmp_path, callbacks, stream=repeat)
    first = {d.subspace: d for d in RunDir(first_task["root"]).decisions()}
    for d in RunDir(tmp_path).decisions()[2:]:
        with np.load(tmp_path / "search" / f"task_03_{d.subspace}.npz") as f:
            alphas, losses = f["alphas"], f["losses"]
        rows = module.task_alphas(d.subspace)[:2, :].numpy()  # tasks 0 and 1, before task 2
        # the earlier tasks' points are raced first and scored on every batch ...
        np.testing.assert_array_equal(alphas[:2], rows)
        assert alphas.shape == (2 + 32, 3) and d.l_prev == pytest.approx(float(losses.min()))
        # ... so the repeat scores task 0's own point as task 0 was scored: its loss
        assert losses[0] == pytest.approx(first[d.subspace].l_curr, rel=1e-5)
        assert d.l_prev <= losses[0]


# --- the decision itself ------------------------------------------------------------------------
# --- the decision itself ------------------------------------------------------------------------


def _two_anchor_module() -> HiSPO:
    m = HiSPO(**SIZES)
    for name in SUBSPACES:
        m.set_task_alpha(0, name, torch.ones(1))
        m.add_anchor(name)
    m.task_index = 1
    return m


def test_decide_keeps_when_the_previous_subspace_is_worse():
    m = _two_anchor_module()
    res = SearchResult(l_curr=1.0, alpha_curr=[0.3, 0.7], l_prev=2.0, alpha_prev=[1.0, 0.0])
    d = SubspacePruning()._decide(m, "high", res, eps=0.0)
    assert d.decision == "keep" and d.anchors == 2 and d.task == 1
    assert isinstance(d, LossDecision) and (d.l_prev, d.alpha_curr) == (2.0, [0.3, 0.7])
    assert m.n_anchors("high") == 2
    torch.testing.assert_close(m.task_alphas("high"), torch.tensor([[1.0, 0.0], [0.3, 0.7]]))


def test_tolerances_left_unset_are_the_task_familys():
    from hispo_pl.task_families import FAMILIES

    point, game = FAMILIES["pointmaze"], FAMILIES["amazeville"]
    assert point.pruning_eps != game.pruning_eps  # the families do differ
    unset = SubspacePruning()
    for family in (point, game):
        assert [unset.tolerance(n, family) for n in ("high", "low")] == [
            family.pruning_eps["high"],
            family.pruning_eps["low"],
        ]
        assert unset.tolerance("policy", family) == min(family.pruning_eps.values())
    given = SubspacePruning(eps_low=0.3)  # what is given wins; the rest stays the family's
    assert given.tolerance("low", game) == 0.3
    assert given.tolerance("high", game) == game.pruning_eps["high"]
    assert given.tolerance("policy", game) == 0.3  # named nowhere: the largest given


def test_decide_prunes_at_the_boundary_and_stores_the_previous_point():
    m = _two_anchor_module()
    res = SearchResult(l_curr=1.0, alpha_curr=[0.3, 0.7], l_prev=1.5, alpha_prev=[1.0, 0.0])
    pruning = SubspacePruning()
    assert pruning._decide(m, "high", res, eps=0.1).decision == "keep"  # 1.5 > 1.1
    d = pruning._decide(m, "low", res, eps=0.5)  # 1.5 <= 1.5: prune
    assert d.decision == "prune" and d.anchors == 1 and d.eps == 0.5
    assert m.n_anchors("low") == 1
    assert m.task_alphas("low").tolist() == [[1.0], [1.0]]


# --- order and type checks ----------------------------------------------------------------------


def _fit_expecting(module, callbacks, root, error, match):
    with pytest.raises(error, match=match):
        _fit(module, 0, root, callbacks)


def test_pruning_before_search_is_rejected(tiny_umaze, tmp_path):
    cbs = [AnchorExtension(), SubspacePruning(), DirichletEvaluation(), RolloutEvaluation()]
    _fit_expecting(HiSPO(**SIZES), cbs, tmp_path, ValueError, "DirichletEvaluation callback")
    _fit_expecting(HiSPO(**SIZES), [SubspacePruning()], tmp_path, ValueError, "DirichletEvaluation")


def test_rollout_before_pruning_is_rejected(tiny_umaze, tmp_path):
    cbs = [DirichletEvaluation(), RolloutEvaluation(), SubspacePruning()]
    _fit_expecting(HiSPO(**SIZES), cbs, tmp_path, ValueError, "after SubspacePruning")


@pytest.mark.parametrize("callback", [AnchorExtension, DirichletEvaluation, SubspacePruning])
def test_subspace_callbacks_reject_a_plain_hbc(tiny_umaze, tmp_path, callback):
    cbs = [callback()] if callback is not SubspacePruning else [DirichletEvaluation(), callback()]
    hbc = HBC(**SIZES)
    _fit_expecting(hbc, cbs, tmp_path, TypeError, "Subspaces protocol, e.g. hispo_pl")


class RecordLogger(Logger):
    """Keeps every ``log_metrics`` call: (step, metrics)."""

    def __init__(self):
        super().__init__()
        self.calls: list[tuple[int, dict]] = []

    name, version = "record", 0

    def log_metrics(self, metrics, step=None):
        self.calls.append((step, dict(metrics)))

    def log_hyperparams(self, params, *args, **kwargs):
        pass


def test_periodic_search_logs_losses_without_deciding(first_task, tmp_path):
    module = _after_first_task()
    module.load_checkpoint_file(first_task["ckpt"])
    module.task_index = 1
    logger = RecordLogger()
    search = DirichletEvaluation(n_candidates=8, n_batches=2, every_n_steps=2)
    trainer = quiet_trainer(
        max_steps=5,
        logger=logger,
        default_root_dir=tmp_path,
        callbacks=[AnchorExtension(), search],
    )
    trainer.fit(module, datamodule=TaskDataModule(STREAM[1], batch_size=64, stream=STREAM))
    searched = [(step, m) for step, m in logger.calls if any("search/" in k for k in m)]
    assert [step for step, _ in searched] == [2, 4]  # not at step 5: that is the task end
    for _, m in searched:
        assert set(m) == {f"search/{n}/{x}" for n in SUBSPACES for x in ("l_prev", "l_curr")}
        assert all(v >= 0 for v in m.values())
    # the periodic searches decide and save nothing; the task-end one saves its losses
    assert [module.n_anchors(n) for n in SUBSPACES] == [2, 2]
    assert sorted(p.name for p in (tmp_path / "search").iterdir()) == [
        "task_02_high.npz",
        "task_02_low.npz",
    ]


def test_periodic_search_rejects_a_negative_period():
    with pytest.raises(ValueError, match="every_n_steps"):
        DirichletEvaluation(every_n_steps=-1)


def test_refine_current_takes_a_better_point_of_the_grown_subspace():
    """The trained weights are replaced only by a point with a lower loss on the same batches."""
    from hispo_pl.callbacks.loss_search import _refine
    from hispo_pl.decisions import extended_subspace_candidates
    from hispo_pl.race import race_candidates

    target = torch.tensor([0.0, 0.0, 1.0])  # the loss is lowest at the new anchor alone

    def score(alphas, batch):
        return (alphas - target).pow(2).sum(-1) + batch["offset"]

    batches = [{"offset": torch.tensor(0.5)}] * 3
    trained = torch.tensor([0.3, 0.3, 0.4])

    def refine(result, trained):
        cands = extended_subspace_candidates(64, trained, torch.Generator().manual_seed(0))
        _refine(result, cands, race_candidates(score, cands, batches, batches[0], survivors=8))

    result = SearchResult(
        l_curr=float(score(trained[None], batches[0])[0]), alpha_curr=trained.tolist()
    )
    refine(result, trained)
    assert result.alpha_curr == [0.0, 0.0, 1.0] and result.l_curr == pytest.approx(0.5)
    assert result.l_trained == pytest.approx(0.5 + 0.3**2 + 0.3**2 + 0.6**2)

    # trained weights already at the optimum: kept, and no l_trained recorded
    kept = SearchResult(l_curr=0.5, alpha_curr=target.tolist())
    refine(kept, target)
    assert kept.alpha_curr == target.tolist() and kept.l_trained is None
