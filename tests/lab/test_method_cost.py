"""``benchmarks/method_cost.py`` measures the product's own steps: its PNN-k is the module the
loop trains on task k, and the operations it counts for HBC are exactly the matmuls of the step
that ``benchmarks/step_speed.py`` builds its floor from."""

from __future__ import annotations

import torch
from helpers import load_benchmark, random_batch

method_cost, step_speed = load_benchmark("method_cost"), load_benchmark("step_speed")


def test_pnn_k_trains_only_its_newest_column_as_on_task_k():
    module = method_cost.build("PNN-3", 4, 2)
    assert module.n_columns == 3 and module.task_column.tolist() == [0, 1]
    trainable = {id(p) for p in module.parameters() if p.requires_grad}
    newest = {id(p) for policy in module._policies() for p in policy.net.column_parameters(2)}
    assert trainable == newest


def test_counted_operations_are_the_steps_matmuls():
    batch = random_batch(n=32)
    torch.manual_seed(0)
    hbc = method_cost.step_flops(method_cost.build("HBC", 4, 2), batch)
    dims = {"obs": 4, "action": 2, "goal": 2}
    assert step_speed.step_networks("HBC", dims) == [(13, 64, 2), (9, 256, 2)]
    assert step_speed.step_networks("BC", dims) == [(13, 256, 4)]
    matmuls = step_speed.step_gemms("HBC", dims, 32)
    assert hbc == sum(2 * b * n_in * n_out for _, (b, n_in, n_out) in matmuls)
    pnn = [method_cost.step_flops(method_cost.build(f"PNN-{k}", 4, 2), batch) for k in (1, 2, 3)]
    assert pnn[0] == hbc  # one column is HBC's networks
    assert pnn[1] - pnn[0] < pnn[2] - pnn[1]  # each column costs more than the one before
