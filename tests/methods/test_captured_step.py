"""The captured training step (``optim.captured``, hispo_pl.nn.program) computes the usual step:
same losses, gradients and parameters after each update, eagerly on the CPU and captured as a
CUDA graph on a GPU; groups of batches train as the same number of single steps."""

from __future__ import annotations

import copy

import lightning as L
import pytest
import torch
from test_fast_step import CASES, _Recorder, make_batch, seeded_bytes
from torch.utils.data import DataLoader

from hispo_pl.config import BackboneConfig, OptimConfig
from hispo_pl.data.sampler import stack_batches
from hispo_pl.errors import ConfigError, TrainingDivergedError
from hispo_pl.modules import CSP, HBC, HiSPO
from hispo_pl.nn import fast
from hispo_pl.nn.program import ProgramOptimizer, TrainingProgram, lr_table

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


def _captured(module):
    """A copy of ``module`` whose step is the captured one."""
    other = copy.deepcopy(module)
    other.optim_config = OptimConfig(
        lr=module.lr, schedule=module.optim_config.schedule, captured=True
    )
    other.automatic_optimization = False
    return other


def test_lr_table_is_the_eager_schedule():
    opt = torch.optim.Adam([torch.zeros(1, requires_grad=True)], lr=1e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=50)
    eager = []
    for _ in range(50):
        eager.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert lr_table(1e-3, "cosine", 50) == eager
    assert lr_table(1e-3, "constant", 50) == lr_table(1e-3, "cosine", -1) == [1e-3]


@pytest.mark.parametrize("case", ["hbc", "bc", "hispo-4", "hilow-3", "cspo-2"])
def test_program_body_is_the_eager_step(case, monkeypatch):
    """Loss, every gradient and every parameter after each of four updates (cosine schedule
    over six), the dropout bytes and anchor-weight noise the same on both sides."""
    torch.manual_seed(0)
    eager = CASES[case]()
    program_module = copy.deepcopy(eager)
    batches = [make_batch(64) for _ in range(4)]
    params_e = [p for p in eager.parameters() if p.requires_grad]
    params_p = [p for p in program_module.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params_e, lr=3e-3, fused=True)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=6)
    program = TrainingProgram(
        program_module.losses, params_p, lr_table(3e-3, "cosine", 6), torch.device("cpu")
    )
    assert not program.capture  # the body runs eagerly off CUDA
    eager.train(), program_module.train()
    for step, batch in enumerate(batches):
        monkeypatch.setattr(fast, "dropout_bytes", seeded_bytes(step))
        torch.manual_seed(100 + step)
        opt.zero_grad(set_to_none=True)
        losses = eager.losses(batch)
        losses["loss"].backward()
        grads = [p.grad.clone() for p in params_e]
        lr = opt.param_groups[0]["lr"]
        opt.step()
        sched.step()
        monkeypatch.setattr(fast, "dropout_bytes", seeded_bytes(step))
        torch.manual_seed(100 + step)
        program.run(batch)
        assert program.losses.keys() == losses.keys()
        for key, value in losses.items():
            torch.testing.assert_close(program.losses[key], value.detach(), rtol=1e-5, atol=1e-6)
        for g_e, p_p in zip(grads, params_p, strict=True):
            torch.testing.assert_close(p_p.grad, g_e, rtol=1e-4, atol=1e-6)
        for p_e, p_p in zip(params_e, params_p, strict=True):
            torch.testing.assert_close(p_p, p_e, rtol=1e-5, atol=1e-6)
        assert float(program.lr) == pytest.approx(lr, rel=1e-6)  # the update's rate
    assert int(program.updates) == 4 and program.nonfinite_update() is None


def _fit(module, batches, max_steps, every=1, logger=None):
    trainer = L.Trainer(
        max_steps=max_steps,
        logger=logger if logger is not None else False,
        log_every_n_steps=every,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        accelerator="cpu",
    )
    trainer.fit(module, DataLoader(batches, batch_size=None))
    return trainer


def _state(module):
    return {k: v.detach().clone() for k, v in module.state_dict().items()}


def _assert_states_close(a, b, rtol=1e-5, atol=1e-6):
    assert a.keys() == b.keys()
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=rtol, atol=atol, msg=key)


@pytest.mark.parametrize("case", ["hbc", "hispo-2"])
@pytest.mark.parametrize("every", [1, 3])
def test_captured_fit_trains_and_logs_as_the_usual_step(case, every):
    """Through the Trainer: the same parameters after seven steps of a cosine schedule, the
    same ``global_step``, and the logger gets the same rows."""
    batches = [make_batch(32) for _ in range(7)]
    torch.manual_seed(0)
    usual = CASES[case]()
    captured = _captured(usual)
    states, rows = [], []
    for module in (usual, captured):
        torch.manual_seed(1)
        recorder = _Recorder()
        trainer = _fit(module, batches, 7, every, recorder)
        assert trainer.global_step == 7
        states.append(_state(module))
        rows.append(recorder.rows)
    assert captured.automatic_optimization is False
    assert isinstance(captured.trainer.optimizers[0], ProgramOptimizer)
    _assert_states_close(*states)
    assert rows[0].keys() == rows[1].keys() and len(rows[0]) == 7 // every
    for step, row in rows[0].items():
        assert rows[1][step].keys() == row.keys()
        for tag, value in row.items():
            assert rows[1][step][tag] == pytest.approx(value, rel=1e-4, abs=1e-6), (step, tag)


@pytest.mark.parametrize("group", [2, 3])
def test_a_group_of_batches_trains_as_single_steps(group):
    """``group`` updates per Trainer step give the parameters and the logged rows (steps
    counted in updates) of one update per step; the budget cuts the last group short."""
    steps, every = 7, 2
    singles = [make_batch(32) for _ in range(9)]
    groups = [stack_batches(singles[i : i + group]) for i in range(0, 9 - group + 1, group)]
    torch.manual_seed(0)
    base = _captured(CASES["hispo-2"]())
    grouped = copy.deepcopy(base)
    states, rows, trainers = [], [], []
    for module, data in ((base, singles), (grouped, groups)):
        torch.manual_seed(1)
        recorder = _Recorder()
        trainers.append(_fit(module, data, steps, every, recorder))
        states.append(_state(module))
        rows.append(recorder.rows)
    assert trainers[0].global_step == trainers[1].global_step == steps  # updates, not groups
    assert int(grouped._program.updates) == steps
    _assert_states_close(*states)
    # the update-step rows, every ``every`` updates and the task's last (update 6)
    assert set(rows[1]) == {1, 3, 5, 6} and set(rows[0]) >= {1, 3, 5}
    for step, row in rows[1].items():
        want = rows[0].get(step)
        if want is None:  # the single-step run writes its last step only if it is due
            continue
        for tag, value in want.items():
            assert row[tag] == pytest.approx(value, rel=1e-4, abs=1e-6), (step, tag)


def test_a_group_needs_the_captured_step():
    group = stack_batches([make_batch(16), make_batch(16)])
    with pytest.raises(ConfigError, match="optim.captured true"):
        _fit(HBC(4, 2), [group], 1)


def test_a_method_with_its_own_optimiser_refuses_the_captured_step():
    with pytest.raises(ConfigError, match="CSP builds its own optimiser"):
        CSP(4, 2, optim=OptimConfig(captured=True))


def test_the_captured_step_refuses_mixed_precision():
    module = HBC(4, 2, optim=OptimConfig(captured=True))
    trainer = L.Trainer(max_steps=2, precision="bf16-mixed", logger=False, accelerator="cpu")
    with pytest.raises(ConfigError, match="precision is bf16-mixed"):
        trainer.fit(module, DataLoader([make_batch(16)] * 2, batch_size=None))


def test_a_non_finite_loss_stops_the_captured_fit_when_it_is_read():
    batches = [make_batch(32) for _ in range(6)]
    batches[2] = {**batches[2], "action": torch.full_like(batches[2]["action"], float("nan"))}
    module = HBC(4, 2, optim=OptimConfig(captured=True))
    with pytest.raises(TrainingDivergedError, match="at step 3 of task"):
        _fit(module, batches, 6, every=4)


def test_the_captured_step_checkpoints_adams_state(tmp_path):
    """The Trainer saves and restores Adam's state through the program's optimiser."""
    batches = [make_batch(32) for _ in range(3)]
    module = HBC(4, 2, backbone=BackboneConfig(dropout=0.0), optim=OptimConfig(captured=True))
    trainer = _fit(module, batches, 3)
    trainer.save_checkpoint(tmp_path / "c.ckpt")
    saved = torch.load(tmp_path / "c.ckpt", weights_only=True)["optimizer_states"][0]
    inner = module._program.optimizer.state_dict()
    assert saved["param_groups"][0]["params"] == inner["param_groups"][0]["params"]
    assert float(saved["state"][0]["step"]) == 3.0
    fresh = ProgramOptimizer(
        TrainingProgram(module.losses, list(module.parameters()), [1e-3], torch.device("cpu"))
    )
    fresh.load_state_dict(saved)
    torch.testing.assert_close(
        fresh.state_dict()["state"][0]["exp_avg"], saved["state"][0]["exp_avg"]
    )


def test_the_default_step_is_untouched():
    """``captured`` off: automatic optimisation, Lightning's Adam and schedule, no program."""
    module = HBC(4, 2)
    module.trainer = L.Trainer(max_steps=10, logger=False, enable_checkpointing=False)
    built = module.configure_optimizers()
    assert module.automatic_optimization and module._program is None
    assert type(built["optimizer"]) is torch.optim.Adam
    assert isinstance(
        built["lr_scheduler"]["scheduler"], torch.optim.lr_scheduler.CosineAnnealingLR
    )


# --- on a GPU -------------------------------------------------------------------------------


def _without_noise(case):
    torch.manual_seed(0)
    if case == "hbc":
        return HBC(4, 2, backbone=BackboneConfig(dropout=0.0))
    module = HiSPO(
        4, 2, backbone=BackboneConfig(dropout=0.0), anchor_init="random", alpha_noise=0.0
    )
    for _ in range(3):
        for name in module.subspace_names:
            module.add_anchor(name)
    return module


@CUDA
@pytest.mark.parametrize("case", ["hbc", "hispo-4"])
def test_the_captured_graph_replays_the_eager_step_on_a_gpu(case):
    """No dropout or weight noise (a graph's random draws are its own stream): the captured
    replays give the eager updates' losses and parameters."""
    eager = _without_noise(case).cuda().train()
    captured = copy.deepcopy(eager)
    batches = [{k: v.cuda() for k, v in make_batch(256).items()} for _ in range(8)]
    rates = lr_table(1e-3, "cosine", 10)
    runs = []
    for module, capture in ((eager, False), (captured, True)):
        params = [p for p in module.parameters() if p.requires_grad]
        program = TrainingProgram(module.losses, params, rates, torch.device("cuda"), capture, 2)
        losses = []
        for batch in batches:
            program.run(batch)
            losses.append(program.losses["loss"].clone())
        runs.append((program, torch.stack(losses)))
    (_, loss_e), (program_c, loss_c) = runs
    assert program_c.graph is not None
    torch.testing.assert_close(loss_c, loss_e, rtol=1e-4, atol=1e-5)
    _assert_states_close(_state(captured), _state(eager), rtol=1e-4, atol=1e-5)


@CUDA
def test_a_captured_step_and_device_batches_never_wait_for_the_host():
    """With CUDA's sync debug mode set to error, a replayed step and a device sampler's batch
    make no host synchronisation."""
    from test_sampler import _indexed_dataset

    from hispo_pl.data.sampler import DeviceHERSampler, HERConfig

    module = HBC(5, 2).cuda().train()
    sampler = DeviceHERSampler(
        _indexed_dataset(obs_dim=5), HERConfig(waysteps=5), 256, 0, device="cuda"
    )
    params = [p for p in module.parameters() if p.requires_grad]
    program = TrainingProgram(
        module.losses, params, lr_table(1e-3, "cosine", 100), torch.device("cuda")
    )
    for _ in range(5):  # warm-up and capture
        program.run(sampler.sample())
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        for _ in range(5):
            program.run(sampler.sample())
    finally:
        torch.cuda.set_sync_debug_mode("default")
    assert int(program.updates) == 10 and program.nonfinite_update() is None


@CUDA
def test_a_captured_fit_on_a_gpu_with_groups(tmp_path):
    singles = [{k: v.cuda() for k, v in make_batch(128).items()} for _ in range(8)]
    groups = [stack_batches(singles[i : i + 4]) for i in (0, 4)]
    module = HBC(4, 2, optim=OptimConfig(captured=True))
    recorder = _Recorder()
    trainer = L.Trainer(
        max_steps=8,
        accelerator="gpu",
        devices=1,
        logger=recorder,
        log_every_n_steps=4,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
    )
    trainer.fit(module, DataLoader(groups, batch_size=None))
    assert trainer.global_step == 8 and set(recorder.rows) == {3, 7}
    assert module._program.graph is None  # released at the task's end


@pytest.mark.e2e
def test_a_stream_trains_with_the_captured_step_and_device_batches(tiny_umaze, tmp_path):
    """``hispo-pl fit`` end to end on the CPU with every option of the GPU path: HiSPO's
    search, pruning and evaluation run as usual around the captured step."""
    from helpers import fit_tiny_stream

    flags = ["--model.init_args.optim.captured", "true", "--data.sampler", "device"]
    results, run_dir = fit_tiny_stream(
        "hispo",
        tmp_path,
        ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"],
        *flags,
        "--data.group",
        "2",
    )
    assert len(results["R"]) == 2 and (run_dir / "task_02.ckpt").is_file()
    config = (run_dir / "task_02.config.yaml").read_text()
    assert "captured: true" in config and "sampler: device" in config


def test_the_programs_example_runs_as_written():
    import doctest

    from hispo_pl.nn import program

    finder, runner = doctest.DocTestFinder(), doctest.DocTestRunner()
    found = finder.find(program.TrainingProgram, "TrainingProgram", globs=vars(program).copy())
    (test,) = [t for t in found if t.name == "TrainingProgram"]
    runner.run(test)
    assert runner.summarize(verbose=False) == (0, len(test.examples)) and test.examples
