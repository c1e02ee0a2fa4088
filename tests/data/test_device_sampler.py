"""HER batches drawn on the run's device (``--data.sampler device``): the host sampler's keys,
rows and distributions, from a seeded torch generator, and groups of batches per step."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import stats
from test_sampler import _indexed_dataset

from hispo_pl.data.batch_stream import _Batches
from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.data.sampler import DeviceHERSampler, HERConfig, HERSampler, MixedSampler

DEVICES = [
    "cpu",
    pytest.param(
        "cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
    ),
]


def _rows(batch: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """The dataset rows a batch of :func:`_indexed_dataset` holds (its features are rows)."""
    as_rows = lambda t: t.cpu().numpy()[:, 0].round().astype(np.int64)  # noqa: E731
    return {
        "row": as_rows(batch["observation"]),
        "goal": as_rows(batch["goal"]),
        "subgoal": as_rows(batch["subgoal"]),
    }


@pytest.mark.parametrize("device", DEVICES)
def test_device_batches_have_the_host_keys_shapes_and_rows(device):
    data = _indexed_dataset()
    cfg = HERConfig(waysteps=5, temperature=10.0, goal_horizon="segment")
    host = HERSampler(data, cfg, batch_size=512, seed=0, transitions=True).sample()
    on_device = DeviceHERSampler(data, cfg, 512, seed=0, transitions=True, device=device).sample()
    assert on_device.keys() == host.keys()
    for key, value in on_device.items():
        assert value.device.type == device and value.dtype == host[key].dtype, key
        assert value.shape == host[key].shape, key
    rows = _rows(on_device)
    end, segment = data.episode_end[rows["row"]], data.segment_end[rows["row"]]
    assert np.isin(rows["row"], data.sample_index).all()
    assert (rows["goal"] >= rows["row"]).all() and (rows["goal"] <= segment).all()
    assert (rows["subgoal"] >= rows["row"]).all() and (rows["subgoal"] <= end).all()
    np.testing.assert_array_equal(on_device["action"].cpu().numpy()[:, 0], rows["row"])
    np.testing.assert_array_equal(on_device["next_position"].cpu().numpy()[:, 0], rows["row"] + 1)


@pytest.mark.parametrize("device", DEVICES)
def test_device_batches_are_a_function_of_the_seed(device):
    data, cfg = _indexed_dataset(), HERConfig(waysteps=5, temperature=10.0)
    a, b, c = (DeviceHERSampler(data, cfg, 256, seed=s, device=device) for s in (3, 3, 4))
    for _ in range(2):
        x, y, z = a.sample(), b.sample(), c.sample()
        assert all(torch.equal(x[k], y[k]) for k in x)
        assert not torch.equal(x["goal"], z["goal"])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("strategy", ["exponential", "uniform", "geometric"])
@pytest.mark.parametrize("horizon", ["episode", "segment"])
def test_sampled_goals_follow_the_host_samplers_distribution(device, strategy, horizon):
    """Fixed seeds, 60,000 samples a side: the rows, goal offsets, goal rows and subgoal
    offsets of the two samplers pass a two-sample KS test, and their histograms agree within
    a few points of sampling noise."""
    data = _indexed_dataset()
    cfg = HERConfig(waysteps=20, temperature=30.0, strategy=strategy, goal_horizon=horizon)
    n = 60_000
    host = _rows(HERSampler(data, cfg, batch_size=n, seed=11).sample())
    dev = _rows(DeviceHERSampler(data, cfg, n, seed=12, device=device).sample())
    samples = {}
    for name, r in (("host", host), ("device", dev)):
        samples[name] = {
            "row": r["row"],
            "goal": r["goal"],
            "goal offset": r["goal"] - r["row"],
            "subgoal offset": r["subgoal"] - r["row"],
        }
    for quantity in samples["host"]:
        a, b = samples["host"][quantity], samples["device"][quantity]
        assert stats.ks_2samp(a, b).pvalue > 1e-3, quantity
        bins = np.unique(np.concatenate([a, b]))
        if len(bins) > 200:  # goal rows and offsets: 50 quantile bins of the host's
            bins = np.unique(np.quantile(a, np.linspace(0, 1, 51)))
        edges = np.append(bins, bins[-1] + 1)
        ha = np.histogram(a, edges)[0] / n
        hb = np.histogram(b, edges)[0] / n
        noise = np.sqrt(np.maximum(ha, 1 / n) * 2 / n)
        assert np.all(np.abs(ha - hb) <= 5 * noise + 1e-4), quantity


def test_the_exponential_mean_is_the_temperature_on_long_episodes():
    long = _indexed_dataset(lengths=[5000, 5000])
    cfg = HERConfig(waysteps=5, temperature=40.0)
    rows = _rows(DeviceHERSampler(long, cfg, 50_000, seed=0).sample())
    far = long.episode_end[rows["row"]] - rows["row"] > 1000  # goals never clipped
    assert (rows["goal"] - rows["row"])[far].mean() == pytest.approx(40.0, rel=0.03)


def test_groups_are_consecutive_batches_on_the_host_and_one_draw_on_the_device():
    data, cfg = _indexed_dataset(), HERConfig(waysteps=5, temperature=10.0)
    group = HERSampler(data, cfg, batch_size=32, seed=5).sample_group(3)
    one_by_one = HERSampler(data, cfg, batch_size=32, seed=5)
    for j in range(3):
        single = one_by_one.sample()
        assert all(torch.equal(group[k][j], single[k]) for k in single)
    on_device = DeviceHERSampler(data, cfg, 32, seed=5).sample_group(3)
    assert {k: v.shape[:2] for k, v in on_device.items()} == {k: (3, 32) for k in on_device}
    mixed = MixedSampler([HERSampler(data, cfg, 32, seed=s) for s in (1, 2)], batch_size=32)
    assert mixed.sample_group(2)["goal"].shape == (2, 32, 2)
    stream = iter(_Batches(HERSampler(data, cfg, batch_size=32, seed=5), steps=2, group=3))
    assert torch.equal(next(stream)["goal"], group["goal"])


def test_the_datamodule_draws_on_the_device_when_asked(tiny_umaze):
    dm = TaskDataModule("pointmaze-umaze-N[6]", batch_size=16, sampler="device", group=2)
    dm.prepare_data()
    dm.setup()
    loader = dm.train_dataloader()  # no Trainer: the CPU
    assert isinstance(loader.dataset.sampler, DeviceHERSampler)
    batch = next(iter(loader))
    assert batch["action"].shape == (2, 16, 2)
    host = TaskDataModule("pointmaze-umaze-N[6]", batch_size=16)
    host.prepare_data()
    host.setup()
    assert isinstance(host.train_dataloader().dataset.sampler, HERSampler)
    with pytest.raises(ValueError, match="--data.group must be >= 1"):
        TaskDataModule("pointmaze-umaze-N[6]", group=0)
    with pytest.raises(ValueError, match="--data.sampler must be host or device"):
        TaskDataModule("pointmaze-umaze-N[6]", sampler="gpu")
