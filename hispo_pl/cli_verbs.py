"""The subcommands that do not go through LightningCLI: ``hispo-pl data`` (make and list
expert datasets), ``evaluate`` (roll out a checkpoint on any task) and ``render`` (draw mazes
with a dataset's or a policy's paths)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from .cli_common import add_num_threads_argument, flip_note, set_num_threads
from .cli_errors import VerbParser
from .errors import Interrupted, UserError

if TYPE_CHECKING:  # torch and Lightning are imported when a verb runs, not for its --help
    from .modules.hbc import GoalConditionedBC


def data_main(argv: list[str]) -> int:
    from .data.datasets import (
        dataset_problem,
        dataset_stats,
        known_dataset_names,
        local_dataset_id,
    )
    from .data.generation import DEFAULT_SEED, generate_dataset

    parser = VerbParser(prog="hispo-pl data", description="Expert datasets")
    sub = parser.add_subparsers(dest="cmd", required=True)
    gen = sub.add_parser("generate", help="collect expert episodes into a local Minari dataset")
    gen.add_argument("names", nargs="+", help=f"maze datasets: {', '.join(known_dataset_names())}")
    gen.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="episodes per maze (default: 500; the paper's 100 for amazeville, 250 for simpletown)",
    )
    gen.add_argument("--seed", type=int, default=DEFAULT_SEED)
    gen.add_argument(
        "--noise",
        type=float,
        default=None,
        help="Gaussian action noise std in env units (default: the expert's: 0.2 point, 0.04 ant)",
    )
    gen.add_argument(
        "--expert-weights",
        default=None,
        help="AntMaze: the D4RL ant policy .npz (default: $HISPO_ANT_EXPERT, else "
        "../shared/experts/d4rl_antmaze_goal_policy.npz)",
    )
    gen.add_argument("--overwrite", action="store_true", help="replace an existing dataset")
    sub.add_parser("list", help="our local datasets and their descriptions")
    args = parser.parse_args(argv)
    if args.cmd == "generate":
        if args.episodes is not None and args.episodes < 1:
            parser.error(f"--episodes must be >= 1, got {args.episodes}")
        if args.noise is not None and not args.noise >= 0:
            parser.error(f"--noise must be >= 0, got {args.noise}")
        for name in args.names:
            try:
                dataset_id = generate_dataset(
                    name,
                    episodes=args.episodes,
                    seed=args.seed,
                    noise=args.noise,
                    overwrite=args.overwrite,
                    expert_weights=args.expert_weights,
                )
            except KeyboardInterrupt:
                raise Interrupted(
                    f"interrupted while making the {name} dataset: the episodes collected so far "
                    "are kept; rerun the same command to continue"
                ) from None
            print(json.dumps(dataset_stats(dataset_id), indent=2))
    else:
        for name in known_dataset_names():
            dataset_id = local_dataset_id(name)
            problem = dataset_problem(dataset_id)
            if problem is None:
                print(json.dumps(dataset_stats(dataset_id), indent=2))
            elif problem != "missing":
                print(
                    f"hispo-pl data: {dataset_id} is {problem}; it counts as missing: rebuild "
                    f"it with\n  hispo-pl data generate {name}",
                    file=sys.stderr,
                )
    return 0


def add_checkpoint_arguments(parser: argparse.ArgumentParser, required: bool) -> None:
    """``--ckpt`` and ``--as-task``, shared by the commands that act with a checkpoint."""
    parser.add_argument(
        "--ckpt", required=required, help="a task_XX.ckpt of a stream run, or any fit"
    )
    parser.add_argument(
        "--as-task",
        type=int,
        default=None,
        help="act with the policy of the stream's task K (1-based); default: the last trained",
    )


def load_checkpoint_policy(
    parser: argparse.ArgumentParser, ckpt: str, as_task: int | None, tasks: list
) -> tuple[GoalConditionedBC, int]:
    """The module a checkpoint holds and the 0-based index of the task whose policy acts
    (``as_task`` counts from 1; default the last trained). A missing file, or tasks whose
    observations or actions the module was not built for, stop with a usage error rather
    than a shape error deep in a rollout."""
    from .modules.hbc import GoalConditionedBC

    if not Path(ckpt).is_file():
        parser.error(f"no checkpoint at {ckpt}")
    module = GoalConditionedBC.from_checkpoint_file(ckpt)
    trained = module.task_index + 1  # tasks whose policy the checkpoint holds
    if as_task is not None and not 1 <= as_task <= trained:
        parser.error(
            f"--as-task {as_task}: {ckpt} holds the policies of tasks 1..{trained} "
            f"(default: {trained}, the last trained)"
        )
    for task in tasks:
        for dim in ("obs_dim", "action_dim"):
            built, needed = getattr(module, dim), getattr(task.env_family, dim)
            if built != needed:
                parser.error(
                    f"{ckpt} was trained with {dim} {built}, but {task} has {dim} {needed}"
                )
    return module, module.task_index if as_task is None else as_task - 1


def other_task_note(ckpt: str, as_task: int, tasks: list) -> str | None:
    """A line naming the task a stream run's policy ``as_task`` (0-based) was trained on, when
    some of ``tasks`` is another maze or variant: acting with the right maze's policy on the
    wrong variant fails, and the note says why before the figures do."""
    from .rundir import RunDir
    from .tasks import parse_task

    spec = RunDir(Path(ckpt).parent).stream_task(as_task)
    if spec is None:
        return None
    own = parse_task(spec)
    others = [
        t for t in tasks if (t.family, t.maze, t.variant) != (own.family, own.maze, own.variant)
    ]
    if not others:
        return None
    return (
        f"[hispo-pl] note: the policy of task {as_task + 1} was trained on {own}; "
        f"acting on {', '.join(str(t) for t in others)}"
    )


def evaluate_main(argv: list[str]) -> int:
    """``hispo-pl evaluate``: any checkpoint on any task, seen or not."""
    parser = VerbParser(
        prog="hispo-pl evaluate", description="Roll out a checkpoint's policy on a task"
    )
    add_checkpoint_arguments(parser, required=True)
    parser.add_argument("--task", required=True, help="task spec, e.g. pointmaze-medium-IO")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    add_num_threads_argument(parser)
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    set_num_threads(args.num_threads)
    from .evaluation import RolloutEvaluator, module_policy
    from .tasks import parse_task, unseen_variant_tasks

    try:
        task = parse_task(args.task)
    except UserError as err:
        parser.error(f"--task: {err}")
    module, as_task = load_checkpoint_policy(parser, args.ckpt, args.as_task, [task])
    note = other_task_note(args.ckpt, as_task, [task])
    if note and not args.json:
        print(note)
    if unseen_variant_tasks([task], module.backbone_config.reads_observation):
        print(
            f"[hispo-pl] note: this policy reads no observation, so {task} looks to it exactly "
            f"like {task.family}-{task.maze}-N",
            file=sys.stderr,
        )
    evaluator = RolloutEvaluator(task, args.episodes, args.seed)
    result = evaluator.run(module_policy(module, task=as_task), progress=not args.json)
    out = {
        "checkpoint": args.ckpt,
        "method": type(module).__name__,
        "task": task.spec,
        "as_task": as_task + 1,
        "episodes": result.episodes,
        "success": result.success,
        "episode_length": result.episode_length,
        "flip_rate": result.flip_rate,
    }
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"[hispo-pl] {out['method']} ({args.ckpt}, policy of task {out['as_task']}) on "
            f"{task}: success {100 * result.success:.1f}% over {result.episodes} episodes, "
            f"mean episode length {result.episode_length:.1f}{flip_note(result.flip_rate)}"
        )
    return 0


def expand_render_tasks(names: list[str]) -> list:
    """Task specs, where a bare family name (``amazeville``, ``simpletown``) stands for every
    maze of that family, so one word draws a whole game."""
    from .task_families import FAMILIES
    from .tasks import parse_task

    specs: list[str] = []
    for name in names:
        specs += [f"{name}-{maze}" for maze in FAMILIES[name].mazes] if name in FAMILIES else [name]
    return [parse_task(spec) for spec in specs]


def render_main(argv: list[str]) -> int:
    """``hispo-pl render``: mazes from above, optionally with a dataset's or a policy's paths."""
    from .data.datasets import DatasetNotFoundError
    from .tasks import TaskSpecError

    parser = VerbParser(
        prog="hispo-pl render",
        description="Draw mazes from above (PNG), with a dataset's or a policy's trajectories",
    )
    parser.add_argument(
        "tasks",
        nargs="+",
        help="task specs (amazeville-HXOO, pointmaze-umaze), or a family name for all its "
        "mazes (amazeville, simpletown)",
    )
    parser.add_argument("--out", required=True, help="image file to write, e.g. mazes.png")
    parser.add_argument(
        "--dataset", action="store_true", help="overlay episodes of each task's stored dataset"
    )
    add_checkpoint_arguments(parser, required=False)
    parser.add_argument(
        "--episodes", type=int, default=20, help="dataset episodes or rollouts per maze"
    )
    parser.add_argument("--seed", type=int, default=0, help="rollouts' start and goal draws")
    parser.add_argument("--columns", type=int, default=None, help="panels per row (default 4)")
    add_num_threads_argument(parser)
    args = parser.parse_args(argv)
    set_num_threads(args.num_threads)
    if args.dataset and args.ckpt:
        parser.error("--dataset and --ckpt overlay different paths: pick one")
    if args.as_task is not None and not args.ckpt:
        parser.error("--as-task picks a checkpoint's policy: it needs --ckpt")
    if args.episodes <= 0:
        parser.error("--episodes must be positive")
    try:
        from . import render
    except ModuleNotFoundError as err:
        if err.name != "matplotlib":
            raise
        print("hispo-pl render: needs matplotlib (pip install matplotlib)", file=sys.stderr)
        return 2
    from matplotlib.backend_bases import FigureCanvasBase

    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = Path(args.out).suffix.lstrip(".").lower()
    if suffix not in formats:  # known before any rollout is spent
        parser.error(f"--out {args.out}: name an image file ({', '.join(sorted(formats))})")
    try:
        tasks = expand_render_tasks(args.tasks)
        overlays = None
        if args.dataset:
            overlays = [render.Overlay(render.dataset_paths(t, args.episodes)) for t in tasks]
        elif args.ckpt:
            from .evaluation import module_policy

            module, as_task = load_checkpoint_policy(parser, args.ckpt, args.as_task, tasks)
            note = other_task_note(args.ckpt, as_task, tasks)
            if note:
                print(note)
            policy = module_policy(module, task=as_task)
            overlays = [render.rollout_paths(t, policy, args.episodes, args.seed) for t in tasks]
    except (TaskSpecError, DatasetNotFoundError) as err:
        print(f"hispo-pl render: {err}", file=sys.stderr)
        return 2
    out = render.render_mazes(tasks, args.out, overlays, args.columns)
    drawn = "" if overlays is None else f" with {sum(len(o.paths) for o in overlays)} paths"
    if overlays is not None and args.ckpt:
        wins = sum(int(o.successes.sum()) for o in overlays)
        drawn += f" ({wins} reached their goal)"
    print(f"[hispo-pl] {len(tasks)} maze(s){drawn}: {out}")
    return 0
