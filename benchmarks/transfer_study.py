"""Does an anchor carry over to the next task? The pruning decision of two-task streams, by
what the low policy sees and how it is trained, measured through ``hispo-pl fit`` itself.

Each (setting, pair) is one HiSPO stream ``[first, second]`` run by the product (module,
datamodule, callbacks, held-out scoring); the study only chooses the overrides and reads the
second task's records from ``decisions.jsonl``: ``L_prev`` (best point of the first task's
anchors) against ``L_curr`` (the grown subspace), on held-out and on training episodes, and how
much ``L_curr`` still fell over the last 20 % of the steps (the convergence diagnostic). A
pair of one task twice (``U-N:U-N``) is the control: the ratio an unchanged task gives, i.e.
what the step budget alone does.

    python benchmarks/transfer_study.py --steps 6000 --jobs 2 \\
        --out docs/results/studies/transfer [--settings obs-fixed subgoal-fixed] [--pairs U-N:L-N]

Runs are resumable (a finished run is read, not rerun); ``--report-only`` rebuilds the table
from the run files under ``--out``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from hispo_pl.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]


def _low(inputs: str, log_std: str) -> list[str]:
    return ["--data.low_inputs", inputs, "--model.init_args.backbone.low_log_std", log_std]


SETTINGS: dict[str, list[str]] = {  # what the low policy sees, and its log-std
    "obs-nll": _low("observation", "null"),  # the observation (PointMaze: x, y, vx, vy), NLL
    "obs-fixed": _low("observation", "0.0"),  # the same, squared error
    "subgoal-fixed": _low("subgoal", "0.0"),  # the subgoal's features only
    "goal-fixed": _low("goal", "0.0"),  # + the goal-space velocity (no observation)
}
MAZES = {"U": "umaze", "M": "medium", "L": "large"}


def pair_stream(pair: str, family: str = "pointmaze", episodes: int = 500) -> list[str]:
    """``U-N:L-N`` → the two task specs of the stream."""
    specs = []
    for short in pair.split(":"):
        maze, _, variant = short.partition("-")
        specs.append(f"{family}-{MAZES.get(maze, maze)}-{variant or 'N'}[{episodes}]")
    if len(specs) != 2:
        raise SystemExit(f"a pair is FIRST:SECOND (e.g. U-N:L-N), got {pair!r}")
    return specs


def run_dir(out: Path, setting: str, pair: str, seed: int) -> Path:
    return Path(out) / setting / pair.replace(":", "_") / f"seed{seed}"


def fit_args(
    out: Path,
    setting: str,
    pair: str,
    seed: int,
    steps: int,
    episodes: int,
    task_episodes: int = 500,
    extra=(),
) -> list[str]:
    """The ``hispo-pl fit`` arguments of one study run (the default HiSPO configuration,
    PointMaze-1's stream config for the budget and logger, the setting's overrides)."""
    return [
        "fit",
        "--config",
        str(ROOT / "configs/streams/pointmaze-1.yaml"),
        "--config",
        str(ROOT / "configs/methods/hispo.yaml"),
        "--data.stream",
        json.dumps(pair_stream(pair, episodes=task_episodes)),
        "--seed_everything",
        str(seed),
        "--num_threads",
        "1",
        "--trainer.max_steps",
        str(steps),
        "--trainer.logger.init_args.save_dir",
        str(Path(out) / setting),
        "--trainer.logger.init_args.name",
        pair.replace(":", "_"),
        "--trainer.enable_progress_bar",
        "false",
        *SETTINGS[setting],
        "--trainer.callbacks.init_args.episodes",  # the last callback: RolloutEvaluation
        str(episodes),
        *extra,
    ]


def second_task_records(path: Path) -> dict[str, dict]:
    """The decision records of the stream's second task, by subspace."""
    return {r["subspace"]: r for r in RunDir(path).read_decisions() if r["task"] == 1}


def table(out: Path, settings, pairs, seeds) -> str:
    """Markdown table of every finished run under ``out``."""
    rows = [
        "| low policy | pair | seed | subspace | L_prev | L_curr | ratio (held-out) | "
        "ratio (train) | convergence | decision | R on 2nd |",
        "|---|---|---:|---|---:|---:|---:|---:|---:|---|---:|",
    ]
    for setting in settings:
        for pair in pairs:
            for seed in seeds:
                path = RunDir(run_dir(out, setting, pair, seed))
                if not path.has_results():
                    continue
                success = path.read_results()["R"][1][1]
                for name, r in second_task_records(path).items():
                    train = r["l_prev_train"] / r["l_curr_train"]
                    rows.append(
                        f"| {setting} | {pair} | {seed} | {name} | {r['l_prev']:.4f} | "
                        f"{r['l_curr']:.4f} | {r['l_prev'] / r['l_curr']:.3f} | {train:.3f} | "
                        f"{r['improvement']:+.1%} | {r['decision']} | {100 * success:.0f} |"
                    )
    return "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=list(SETTINGS))
    parser.add_argument("--pairs", nargs="+", default=["U-N:L-N", "U-N:U-N"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--steps", type=int, default=6000, help="gradient steps per task")
    parser.add_argument("--episodes", type=int, default=100, help="rollouts per evaluation")
    parser.add_argument("--task-episodes", type=int, default=500, help="expert episodes per task")
    parser.add_argument("--jobs", type=int, default=2, help="runs at once (1 thread each)")
    parser.add_argument("--out", type=Path, default=ROOT / "results/transfer-study")
    parser.add_argument("--report-only", action="store_true")
    args = parser.parse_args(argv)
    for pair in args.pairs:
        pair_stream(pair)  # fail on a malformed pair before anything runs

    todo = [
        (s, p, seed)
        for s in args.settings
        for p in args.pairs
        for seed in args.seeds
        if not RunDir(run_dir(args.out, s, p, seed)).has_results()
    ]
    if not args.report_only:

        def run(job) -> None:
            setting, pair, seed = job
            path = run_dir(args.out, setting, pair, seed)
            path.mkdir(parents=True, exist_ok=True)
            cmd = [sys.executable, "-m", "hispo_pl.cli"]
            cmd += fit_args(
                args.out, setting, pair, seed, args.steps, args.episodes, args.task_episodes
            )
            with open(RunDir(path).fit_log, "w") as log:
                code = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
            print(f"{setting} {pair} seed{seed}: exit {code}", flush=True)

        with ThreadPoolExecutor(max(args.jobs, 1)) as pool:
            list(pool.map(run, todo))
    text = table(args.out, args.settings, args.pairs, args.seeds)
    (Path(args.out) / "table.md").parent.mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "table.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
