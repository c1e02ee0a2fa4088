"""The fast training path (hispo_pl.nn.fast) computes today's step: same loss, same gradients,
same optimiser update as plain autograd modules and the default Adam, given the same dropout
bytes."""

from __future__ import annotations

import math
from contextlib import nullcontext

import lightning as L
import pytest
import torch
from lightning.pytorch.loggers import Logger
from torch.utils.data import DataLoader

from hispo_pl.config import BackboneConfig
from hispo_pl.modules import BC, CSP, CSPO, HBC, HiLOW, HiSPO
from hispo_pl.nn import fast
from hispo_pl.nn.mlp import ResidualMLP


def make_batch(n: int = 96, obs_dim: int = 4, action_dim: int = 2) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(7)
    return {
        "observation": torch.randn(n, obs_dim, generator=g),
        "position": torch.randn(n, 2, generator=g),
        "goal": torch.randn(n, 2, generator=g),
        "subgoal": torch.randn(n, 2, generator=g),
        "action": torch.rand(n, action_dim, generator=g) * 2 - 1,
    }


def seeded_bytes(seed: int):
    """A stand-in for ``fast.dropout_bytes`` whose bytes depend only on ``seed`` and the order
    of the calls: one call for three masks gives what three calls for one give."""
    gen = torch.Generator().manual_seed(seed)

    def draw(count, shape, device):
        draws = [
            torch.randint(0, 256, tuple(shape), generator=gen, dtype=torch.uint8)
            for _ in range(count)
        ]
        return torch.stack(draws).to(device)

    return draw


def graph_ops(tensor: torch.Tensor) -> set[str]:
    """Names of the autograd nodes behind ``tensor``."""
    seen, todo, names = set(), [tensor.grad_fn], set()
    while todo:
        node = todo.pop()
        if node is None or node in seen:
            continue
        seen.add(node)
        names.add(type(node).__name__)
        todo.extend(next_fn for next_fn, _ in node.next_functions)
    return names


def step_result(module, batch, reference: bool, monkeypatch):
    """Loss and gradients of one training step, dropout bytes from ``seeded_bytes(0)``, noise
    on the anchor weights from seed 1."""
    monkeypatch.setattr(fast, "dropout_bytes", seeded_bytes(0))
    module.train()
    module.zero_grad(set_to_none=True)
    torch.manual_seed(1)
    with fast.reference_path() if reference else nullcontext():
        loss = module.losses(batch)["loss"]
        loss.backward()
    grads = {n: p.grad.clone() for n, p in module.named_parameters() if p.grad is not None}
    return loss.detach(), grads, graph_ops(loss)


def grown(module, anchors: int):
    for _ in range(anchors - 1):
        for name in module.subspace_names:
            module.add_anchor(name)
    return module


CASES = {
    "hbc": lambda: HBC(4, 2),
    "bc": lambda: BC(4, 2),
    "hispo-2": lambda: grown(HiSPO(4, 2, anchor_init="random"), 2),
    "hispo-4": lambda: grown(HiSPO(4, 2, anchor_init="random"), 4),
    "hilow-3": lambda: grown(HiLOW(4, 2, rank=4, anchor_init="random"), 3),
    "cspo-2": lambda: grown(CSPO(4, 2, anchor_init="random"), 2),
}


@pytest.mark.parametrize("case", list(CASES))
def test_fast_step_matches_reference(case, monkeypatch):
    _fast_step_matches_reference(case, "cpu", monkeypatch)


@pytest.mark.parametrize("case", ["hbc", "hispo-4"])
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_fast_step_matches_reference_on_a_gpu(case, monkeypatch):
    _fast_step_matches_reference(case, "cuda", monkeypatch)


def _fast_step_matches_reference(case, device, monkeypatch):
    torch.manual_seed(0)
    module = CASES[case]().to(device)
    batch = {k: v.to(device) for k, v in make_batch().items()}
    loss_f, grads_f, ops_f = step_result(module, batch, reference=False, monkeypatch=monkeypatch)
    loss_r, grads_r, ops_r = step_result(module, batch, reference=True, monkeypatch=monkeypatch)
    # the two runs took different routes: one node for the network, or autograd per op
    assert "_ResidualMLPFunctionBackward" in ops_f
    assert "_ResidualMLPFunctionBackward" not in ops_r and "GeluBackward0" in ops_r
    torch.testing.assert_close(loss_f, loss_r, rtol=1e-5, atol=1e-5)
    assert grads_f.keys() == grads_r.keys() and grads_f
    scale = max(g.abs().max() for g in grads_r.values())
    for name, g in grads_r.items():
        torch.testing.assert_close(grads_f[name], g, rtol=1e-4, atol=1e-5 * scale, msg=name)
    # what trains is what the reference trains: every trainable parameter got a gradient
    assert set(grads_f) == {n for n, p in module.named_parameters() if p.requires_grad}


DEVICES = [
    "cpu",
    pytest.param(
        "cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
    ),
]


@pytest.mark.parametrize("device", DEVICES)
def test_residual_mlp_function_matches_its_definition(device):
    """Input gradients too (a 3-D input that requires grad), with and without masks, on the
    CPU and on a GPU where there is one."""
    torch.manual_seed(0)
    net = ResidualMLP(5, 16, 3).to(device)
    params = net.parameter_tensors()
    x = torch.randn(2, 7, 5, device=device, requires_grad=True)
    dropout = fast.DropoutDraw(fast.dropout_bytes(3, (2, 7, 16), x.device), 26, 256 / 230)
    for m in (dropout, None):
        out_f = fast.residual_mlp(x, params, m)
        out_r = fast.residual_mlp_reference(x, params, m)
        torch.testing.assert_close(out_f, out_r)
        up = torch.randn_like(out_r)
        grads_f = torch.autograd.grad(out_f, [x, *params], up)
        grads_r = torch.autograd.grad(out_r, [x, *params], up)
        for a, b in zip(grads_f, grads_r, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_dropout_masks_keep_the_byte_threshold_distribution():
    x = torch.zeros(1)
    torch.manual_seed(0)
    a = fast.dropout_masks(3, (512, 256), 26, 256 / 230, x)
    torch.manual_seed(0)
    b = fast.dropout_masks(3, (512, 256), 26, 256 / 230, x)
    for m, same in zip(a, b, strict=True):
        assert torch.equal(m, same)  # a function of the seed
        assert m.unique().tolist() == [0.0, pytest.approx(256 / 230)]
    dropped = torch.stack(a).eq(0).float().mean().item()
    n, p = 3 * 512 * 256, 26 / 256
    assert abs(dropped - p) < 5 * math.sqrt(p * (1 - p) / n)
    assert not torch.equal(a[0], a[1])  # three masks, not one repeated


@pytest.mark.parametrize("reference", [False, True])
def test_optimiser_is_fused_on_the_fast_path_only(reference):
    module = HBC(4, 2)
    module.trainer = L.Trainer(max_steps=10, logger=False, enable_checkpointing=False)
    with fast.reference_path() if reference else nullcontext():
        opt = module.configure_optimizers()["optimizer"]
    assert opt.defaults["fused"] is (not reference)


@pytest.mark.parametrize("method", [HBC, CSP])
def test_a_module_builds_its_optimiser_without_a_trainer(method):
    """As a notebook or a benchmark script steps a module by hand: a constant rate then."""
    module = method(4, 2)
    built = module.configure_optimizers()
    opt = built["optimizer"] if isinstance(built, dict) else built
    assert isinstance(opt, torch.optim.Adam)
    if isinstance(built, dict):  # its schedule holds the rates where there is no step budget
        rates = [g["lr"] for g in opt.param_groups]
        for _ in range(5):
            opt.step()
            built["lr_scheduler"]["scheduler"].step()
        assert [g["lr"] for g in opt.param_groups] == rates
    assert {id(p) for g in opt.param_groups for p in g["params"]} == {
        id(p) for p in module.parameters() if p.requires_grad
    }


def test_fused_adam_update_matches_default_adam():
    torch.manual_seed(0)
    params = [torch.randn(64, 32), torch.randn(32)]
    grads = [[torch.randn_like(p) for p in params] for _ in range(5)]
    results = []
    for fused in (True, False):
        ps = [p.clone().requires_grad_() for p in params]
        opt = torch.optim.Adam(ps, lr=3e-4, fused=fused)
        for step_grads in grads:
            for p, g in zip(ps, step_grads, strict=True):
                p.grad = g.clone()
            opt.step()
        results.append(ps)
    for a, b in zip(*results, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)


def test_eval_and_no_grad_keep_the_plain_modules():
    """Bit for bit, in one process: in eval mode both paths run the same plain modules."""
    torch.manual_seed(0)
    module, batch = HBC(4, 2).eval(), make_batch()
    out = module.act(batch["observation"], batch["position"], batch["goal"])
    with fast.reference_path():
        ref = module.act(batch["observation"], batch["position"], batch["goal"])
    assert torch.equal(out, ref)
    module.train()
    with torch.no_grad():
        loss = module.losses(batch)["loss"]
    assert loss.grad_fn is None


class _Recorder(Logger):
    """Keeps what the Trainer writes: {step: {tag: value}}."""

    def __init__(self):
        super().__init__()
        self.rows: dict[int, dict[str, float]] = {}

    @property
    def name(self) -> str:
        return "recorder"

    @property
    def version(self) -> int:
        return 0

    def log_hyperparams(self, params, *args, **kwargs) -> None:
        pass

    def log_metrics(self, metrics, step=None) -> None:
        self.rows.setdefault(step, {}).update(metrics)


@pytest.mark.parametrize("every", [1, 3])
def test_fast_path_logs_what_the_reference_logs(every):
    """Logging only on the steps the Trainer writes leaves the logger's contents unchanged."""
    batches = [make_batch(32) for _ in range(7)]
    rows = []
    for reference in (False, True):
        torch.manual_seed(0)
        module, recorder = HBC(4, 2, backbone=BackboneConfig(dropout=0.0)), _Recorder()
        trainer = L.Trainer(
            max_steps=len(batches),
            logger=recorder,
            log_every_n_steps=every,
            enable_checkpointing=False,
            enable_progress_bar=False,
            enable_model_summary=False,
        )
        with fast.reference_path() if reference else nullcontext():
            trainer.fit(module, DataLoader(batches, batch_size=None))
        rows.append(recorder.rows)
    fast_rows, reference_rows = rows
    assert fast_rows.keys() == reference_rows.keys() and len(fast_rows) == 7 // every
    for step, row in reference_rows.items():
        assert fast_rows[step].keys() == row.keys() and "train/loss" in row
        for tag, value in row.items():
            assert fast_rows[step][tag] == pytest.approx(value, rel=1e-4), (step, tag)
