"""What HiSPO's task-end search costs as its subspaces grow: the wall time of the product's own
search (:class:`~hispo_pl.callbacks.DirichletEvaluation`: L_curr, the previous subspace's
Dirichlet candidates raced on held-out batches, the refinement of the current weights) with 1 to
``--anchors`` anchors per subspace, on a stream config's first task and its method config's
search settings:

    python benchmarks/search_cost.py --stream pointmaze-1 --anchors 12 [--threads 1] [--rounds 3]

Each count's time is the median over ``--rounds`` searches (after one unmeasured). A long
stream's search after task ``k`` runs at ``k`` anchors or fewer (pruned ones are dropped).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from types import SimpleNamespace

import torch

from hispo_pl.benchmark.plan import stream_config_path
from hispo_pl.callbacks import DirichletEvaluation
from hispo_pl.config_files import config_root
from hispo_pl.fit import run_lightning_cli


def search_setup(stream: str, config_dir: Path):
    """The HiSPO module, its datamodule (first task, set up) and its search callback, as
    ``hispo-pl fit`` builds them for the stream and ``configs/methods/hispo.yaml``."""
    configs = [stream_config_path(stream, config_dir), config_dir / "methods" / "hispo.yaml"]
    args = [a for c in configs for a in ("--config", str(c))] + ["--trainer.logger", "false"]
    cli = run_lightning_cli(args, run=False)
    search = next(c for c in cli.trainer.callbacks if isinstance(c, DirichletEvaluation))
    cli.datamodule.prepare_data()
    cli.datamodule.setup("fit")
    return cli.model, cli.datamodule, search


def search_seconds(module, datamodule, search: DirichletEvaluation, rounds: int) -> float:
    """Median wall seconds of one task-end search of ``module`` as it stands."""
    trainer = SimpleNamespace(datamodule=datamodule)  # what the search reads of its trainer
    times = []
    for i in range(rounds + 1):
        start = time.perf_counter()
        search._run_search(trainer, module, save=False)
        if i:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stream", default="pointmaze-1")
    parser.add_argument("--anchors", type=int, default=12)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--config-dir", type=Path, default=None)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    module, datamodule, search = search_setup(args.stream, args.config_dir or config_root())
    print(f"| anchors per subspace | search seconds ({args.threads} thread(s), {args.stream}) |")
    print("|---:|---:|")
    for k in range(1, args.anchors + 1):
        if k > 1:
            module.task_index = k - 1
            for name in module.subspace_names:
                module.add_anchor(name)
        seconds = search_seconds(module, datamodule, search, args.rounds)
        print(f"| {k} | {seconds:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
