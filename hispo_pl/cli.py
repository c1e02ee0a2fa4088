"""The ``hispo-pl`` command.

- ``hispo-pl fit --config configs/hbc/pointmaze-umaze.yaml``: LightningCLI (fit / validate /
  ``--print_config`` / dotted overrides such as ``--trainer.max_steps 2000``).
- ``hispo-pl data generate pointmaze-umaze``: make a local expert dataset.
- ``hispo-pl data list``: the datasets stored locally.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings

import torch
from lightning.pytorch.cli import LightningCLI

from .data.datamodule import TaskDataModule
from .modules.hbc import GoalConditionedBC


def set_num_threads(n: int) -> None:
    """Torch intra-op threads; 0 keeps torch's default. On 2 shared cores 1 often wins."""
    if n > 0:
        torch.set_num_threads(n)


class HispoCLI(LightningCLI):
    """LightningCLI with task-derived model sizes and a printed result at the end of ``fit``."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_argument(
            "--num_threads",
            type=int,
            default=0,
            help="torch.set_num_threads (0: torch default). Try 1 on a busy 2-core machine.",
        )
        for dim in ("obs_dim", "action_dim", "goal_dim"):
            parser.link_arguments(f"data.{dim}", f"model.init_args.{dim}", apply_on="instantiate")

    def before_instantiate_classes(self) -> None:
        set_num_threads(self.config.get(self.subcommand, self.config).get("num_threads", 0))

    def after_fit(self) -> None:
        from .callbacks import RolloutEvaluation

        for cb in self.trainer.callbacks:
            if isinstance(cb, RolloutEvaluation) and cb.last is not None:
                task = self.datamodule.task
                print(
                    f"[hispo-pl] {type(self.model).__name__} on {task}: success "
                    f"{100 * cb.last['success']:.1f}% over {cb.episodes} episodes, mean episode "
                    f"length {cb.last['episode_length']:.1f}, after {cb.last['step']} steps"
                )
                if self.trainer.log_dir:
                    print(f"[hispo-pl] TensorBoard logs: {self.trainer.log_dir}")


def run_lightning_cli(args: list[str] | None = None) -> HispoCLI:
    return HispoCLI(
        model_class=GoalConditionedBC,
        datamodule_class=TaskDataModule,
        subclass_mode_model=True,
        args=args,
        trainer_defaults={"accelerator": "cpu", "devices": 1},
        save_config_kwargs={"overwrite": True},
    )


def data_main(argv: list[str]) -> int:
    from .data.datasets import (
        DEFAULT_NOISE,
        DEFAULT_SEED,
        dataset_exists,
        dataset_stats,
        generate_dataset,
        known_dataset_names,
        local_dataset_id,
    )

    parser = argparse.ArgumentParser(prog="hispo-pl data", description="Expert datasets")
    sub = parser.add_subparsers(dest="cmd", required=True)
    gen = sub.add_parser("generate", help="collect expert episodes into a local Minari dataset")
    gen.add_argument("names", nargs="+", help=f"maze datasets: {', '.join(known_dataset_names())}")
    gen.add_argument("--episodes", type=int, default=500)
    gen.add_argument("--seed", type=int, default=DEFAULT_SEED)
    gen.add_argument("--noise", type=float, default=DEFAULT_NOISE, help="Gaussian action noise std")
    gen.add_argument("--overwrite", action="store_true", help="replace an existing dataset")
    sub.add_parser("list", help="our local datasets and their descriptions")
    args = parser.parse_args(argv)
    if args.cmd == "generate":
        for name in args.names:
            dataset_id = generate_dataset(
                name,
                episodes=args.episodes,
                seed=args.seed,
                noise=args.noise,
                overwrite=args.overwrite,
            )
            print(json.dumps(dataset_stats(dataset_id), indent=2))
    else:
        for name in known_dataset_names():
            dataset_id = local_dataset_id(name)
            if dataset_exists(dataset_id):
                print(json.dumps(dataset_stats(dataset_id), indent=2))
    return 0


def _quiet_known_warnings() -> None:
    """Silence third-party notices that say nothing about the user's run."""
    for pattern in (
        r".*IterableDataset.*has `__len__` defined.*",
        r".*does not have many workers.*",
        r".*treespec.*LeafSpec.*",
        r".*AdroitHand.*",
        r".*litlogger.*",
        r".*LightningCLI's args parameter.*",
    ):
        warnings.filterwarnings("ignore", message=pattern)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    _quiet_known_warnings()
    if argv and argv[0] == "data":
        return data_main(argv[1:])
    run_lightning_cli(argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
