"""Shared test helpers (imported as ``helpers``: pytest puts this folder on ``sys.path``)."""

from __future__ import annotations

import importlib.util
import json
import shutil
import sys
from pathlib import Path
from types import ModuleType

import lightning as L
import torch

from hispo_pl.callbacks import protocols
from hispo_pl.config import BackboneConfig
from hispo_pl.modules.hispo import HiSPO
from hispo_pl.results import LaunchRecord, StreamResults
from hispo_pl.rundir import RunDir

TIMES = ("wall_time_s", "phase_time_s")  # what two runs of the same work may differ in

SUBSPACE_PROTOCOLS = (
    protocols.ExtendableSubspaces,
    protocols.SearchableSubspaces,
    protocols.PrunableSubspaces,
    protocols.TransferableSubspaces,
    protocols.WeightedSubspaces,
)
"""What HiSPO's callbacks and the loop need of a module with subspaces (CSPO and HiLOW too)."""


def nested_equal(a, b) -> bool:
    """Nested checkpoint contents equal, tensors bit for bit."""
    if torch.is_tensor(a):
        return torch.is_tensor(b) and a.dtype == b.dtype and torch.equal(a, b)
    if isinstance(a, dict):
        return (
            isinstance(b, dict)
            and a.keys() == b.keys()
            and all(nested_equal(a[k], b[k]) for k in a)
        )
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(nested_equal(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def without_times(record: dict) -> dict:
    """A results or progress record without its wall times."""
    return {k: v for k, v in record.items() if k not in TIMES}


def checkpoint_of(module) -> dict:
    """The checkpoint Lightning would save of ``module`` as it stands: its state, its
    hyperparameters and what the module's ``on_save_checkpoint`` adds (its class, its task)."""
    checkpoint = {"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams)}
    module.on_save_checkpoint(checkpoint)
    return checkpoint


def quiet_trainer(max_steps: int, **kwargs) -> L.Trainer:
    """A short CPU Trainer that writes nothing and prints nothing unless ``kwargs`` say so."""
    options = {
        "accelerator": "cpu",
        "logger": False,
        "enable_checkpointing": False,
        "enable_progress_bar": False,
        "enable_model_summary": False,
    }
    return L.Trainer(max_steps=max_steps, **{**options, **kwargs})


ROOT = Path(__file__).resolve().parents[1]
TINY_STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]


def tiny_stream_args(
    method_config: str | Path, save_dir: Path, stream: list[str] = TINY_STREAM, *extra: str
) -> list[str]:
    """``hispo-pl fit`` arguments for a stream of tiny tasks (the ``tiny_umaze`` data): 5 steps
    of batch 64 per task, 2 evaluation episodes, logs under ``save_dir``. ``method_config`` is
    a method name of ``configs/methods`` or a path to a YAML file."""
    config = Path(method_config)
    if not config.suffix:
        config = ROOT / "configs" / "methods" / f"{method_config}.yaml"
    return [
        "fit",
        "--config",
        str(ROOT / "configs/streams/pointmaze-1.yaml"),
        "--config",
        str(config),
        "--data.stream",
        json.dumps(stream),
        "--trainer.max_steps",
        "5",
        "--data.batch_size",
        "64",
        "--trainer.logger.init_args.save_dir",
        str(save_dir),
        "--trainer.callbacks.init_args.episodes",  # the last callback: RolloutEvaluation
        "2",
        "--trainer.enable_progress_bar",
        "false",
        *extra,
    ]


def write_run_files(
    run_dir: Path, results: dict | None = None, launch: dict | None = None
) -> RunDir:
    """A run directory with the ``results.json`` and ``run.json`` given, written as hispo-pl
    writes them (through :class:`RunDir`: the format number first, every key of the record,
    null where a test gives none): ``results`` holds the keys of a
    :class:`~hispo_pl.results.StreamResults`, ``launch`` those of a
    :class:`~hispo_pl.results.LaunchRecord` in the file's order; either may be left out."""
    run = RunDir(run_dir)
    run.path.mkdir(parents=True, exist_ok=True)
    if results is not None:
        run.write_results(StreamResults.from_json(results))
    if launch is not None:
        run.write_run_record(LaunchRecord.from_json(launch))
    return run


def fit_tiny_stream(
    method_config: str | Path, save_dir: Path, stream: list[str] = TINY_STREAM, *extra: str
) -> tuple[dict, Path]:
    """Run :func:`tiny_stream_args` through ``hispo-pl fit``; its results and run dir."""
    from hispo_pl.cli import main

    assert main(tiny_stream_args(method_config, save_dir, stream, *extra)) == 0
    run_dir = save_dir / "pointmaze-1" / "seed0"  # a stream's version defaults to seed<seed>
    return json.loads((run_dir / "results.json").read_text()), run_dir


class DirlessLogger(L.pytorch.loggers.Logger):
    """A logger without a run directory (``log_dir``), as MLflow's or W&B's: it keeps what it
    receives in ``DirlessLogger.received`` (class-level, since the CLI builds the instance)."""

    received: list[tuple[dict, int | None]] = []

    @property
    def name(self) -> str:
        return "dirless"

    @property
    def version(self) -> str:
        return "0"

    @property
    def save_dir(self) -> str:  # where such a logger keeps its own files (./mlruns for MLflow)
        return "dirless-logs"

    def log_metrics(self, metrics: dict, step: int | None = None) -> None:
        DirlessLogger.received.append((dict(metrics), step))

    def log_hyperparams(self, params, *args, **kwargs) -> None:
        pass


# --- a Minari dataset of your own (test_datasets.py, test_cli_stream.py) ------------------------


def own_minari_dataset(
    dataset_id: str, episodes: int = 4, steps: int = 20, obs_dim: int = 4, keys=None
):
    """A small Minari dataset as a user makes one (not ours: no generation settings), of random
    PointMaze-shaped steps unless ``obs_dim`` or ``keys`` say otherwise."""
    import minari
    import numpy as np
    from gymnasium import spaces
    from minari.data_collector import EpisodeBuffer

    keys = keys or {"observation": obs_dim, "achieved_goal": 2, "desired_goal": 2}
    rng = np.random.default_rng(0)
    box = lambda n: spaces.Box(-np.inf, np.inf, (n,), np.float64)  # noqa: E731
    buffers = [
        EpisodeBuffer(
            id=k,
            observations={key: rng.normal(size=(steps + 1, n)) for key, n in keys.items()},
            actions=rng.uniform(-1, 1, size=(steps, 2)),
            rewards=[0.0] * steps,
            terminations=[False] * steps,
            truncations=[False] * (steps - 1) + [True],
        )
        for k in range(episodes)
    ]
    minari.create_dataset_from_buffers(
        dataset_id=dataset_id,
        buffer=buffers,
        observation_space=spaces.Dict({key: box(n) for key, n in keys.items()}),
        action_space=spaces.Box(-1.0, 1.0, (2,), np.float32),
        algorithm_name="random",
        author="you",
        author_email="you@example.org",
        code_permalink="https://example.org",
        description="test data",
    )
    return dataset_id


# --- a tiny HiSPO and its batches (test_hispo*.py) ---------------------------------------------

# Float32 results that went through other kernels than those they are compared with (a fixture
# recorded on another machine, a batched matmul of another batch count, another thread count)
# agree to a few units in the last place, not bit for bit: blocked and vectorised GEMMs and FMA
# change the order of each dot product's sum, and reordering a float32 sum of n terms of size s
# moves it by about sqrt(n)·u·s (at most n·u·s), u = 2^-24 ≈ 6e-8. In the tiny test networks
# (widths ≤ 16, a handful of layers, activations and outputs of order 1) that measured 6e-8 to
# 3e-7 on another x86-64 CPU than the one that recorded the fixtures. The error follows the
# size of the intermediate activations, not of the compared value (an action may be 0.002),
# hence an absolute bound next to the relative one: 3e-6, about 50 ulps at 1, leaves a tenfold
# margin and stays orders of magnitude below what a wrongly loaded weight or a wrong mixing
# weight changes.
FLOAT32_REORDERED = {"rtol": 3e-6, "atol": 3e-6}


HISPO_SIZES = {
    "obs_dim": 4,
    "action_dim": 2,
    "backbone": BackboneConfig(high_hidden=8, low_hidden=16),
}


def tiny_hispo(seed: int = 0, cls: type[HiSPO] = HiSPO, **kw) -> HiSPO:
    """A tiny HiSPO, or a subclass of it (``cls``), with seeded initial weights."""
    torch.manual_seed(seed)
    return cls(**{**HISPO_SIZES, **kw})


def random_batch(n: int = 12, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    dims = {"observation": 4, "position": 2, "goal": 2, "subgoal": 2, "action": 2}
    return {k: torch.randn(n, d, generator=g) for k, d in dims.items()}


def perturb_newest(module: HiSPO, subspace: str, seed: int = 1, scale: float = 0.3) -> None:
    """Move the newest anchor of a subspace away from the others (a "mean" anchor starts at
    their centre, and LayerNorm anchors start identical), so that mixing weights matter."""
    g = torch.Generator().manual_seed(seed)
    k = module.n_anchors(subspace) - 1
    with torch.no_grad():
        for name, p in module.policies[subspace].named_parameters():
            if name.endswith(f".{k}"):
                p.add_(scale * torch.randn(p.shape, generator=g))


def grow_three_tasks(m: HiSPO, perturb) -> HiSPO:
    """``m`` after three tasks: 3 high anchors, 2 low ones (the low extension of task 3 pruned),
    3 stored weight rows; ``perturb(module, subspace, seed)`` moves each new anchor away."""
    for name in ("high", "low"):
        m.set_task_alpha(0, name, torch.ones(1))
    m.freeze_all()
    for name in ("high", "low"):
        m.add_anchor(name)
        perturb(m, name, 11)
    m.set_task_alpha(1, "high", torch.tensor([0.4, 0.6]))
    m.set_task_alpha(1, "low", torch.tensor([0.3, 0.7]))
    m.freeze_all()
    for name in ("high", "low"):
        m.add_anchor(name)
        perturb(m, name, 12)
    m.set_task_alpha(2, "high", torch.tensor([0.2, 0.3, 0.5]))
    m.prune_last_anchor("low")
    m.set_task_alpha(2, "low", torch.tensor([0.5, 0.5]))
    m.task_index = 2
    return m


def act_on(module: HiSPO, task: int | None, seed: int = 3) -> torch.Tensor:
    b = random_batch(7, seed)
    module.eval()
    return module.act(b["observation"], b["position"], b["goal"], task=task)


# --- a tiny benchmark (test_benchmark*.py) -------------------------------------------------------

BENCH_TINY = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
BENCH_TINY_OVERRIDES = [
    "--data.stream",
    json.dumps(BENCH_TINY),
    "--data.batch_size",
    "64",
    "--trainer.callbacks.init_args.episodes",  # the last callback: RolloutEvaluation
    "2",
]


def grid_config_dir(tmp_path: Path, name: str, grid: dict) -> Path:
    """A config dir with the pointmaze-1 stream, the grid's method configs (copies of the
    shipped ones) and the grid itself as ``grids/<name>.yaml``."""
    import yaml

    configs = tmp_path / "configs"
    for sub in ("methods", "streams", "grids"):
        (configs / sub).mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / "configs/streams/pointmaze-1.yaml", configs / "streams")
    for method in grid["methods"]:
        shutil.copy(ROOT / f"configs/methods/{method}.yaml", configs / "methods")
    (configs / "grids" / f"{name}.yaml").write_text(yaml.safe_dump(grid))
    return configs


def benchmark_config_dir(tmp_path: Path, methods: list[str]) -> Path:
    """A config dir with the pointmaze-1 stream and copies of the HiSPO method config."""
    configs = tmp_path / "configs"
    (configs / "methods").mkdir(parents=True)
    (configs / "streams").mkdir()
    shutil.copy(ROOT / "configs/streams/pointmaze-1.yaml", configs / "streams")
    for m in methods:
        shutil.copy(ROOT / "configs/methods/hispo.yaml", configs / "methods" / f"{m}.yaml")
    return configs


def error_lines(err: str) -> list[str]:
    """What a command wrote to stderr apart from its progress lines (``[hispo-pl] ...``):
    the lines a user error must fit in one of."""
    return [line for line in err.splitlines() if not line.startswith("[hispo-pl] ")]


def load_benchmark(name: str) -> ModuleType:
    """The script ``benchmarks/<name>.py`` as a module (the folder is not a package), registered
    in ``sys.modules`` so that its dataclasses find their module."""
    spec = importlib.util.spec_from_file_location(name, ROOT / f"benchmarks/{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module
