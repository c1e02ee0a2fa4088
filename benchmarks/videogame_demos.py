"""Success and speed of the video-game demonstration expert on every maze.

    python benchmarks/videogame_demos.py [--episodes 50] [--mazes amazeville-HOOO ...] [--seed 0]

Runs :class:`hispo_pl.envs.videogame.expert.GameExpert` as the dataset collector does (start
and goal drawn by the layout, the env's step limit, an episode ends on touching the goal) and
prints, per maze: episodes, success %, mean episode length (steps), mean re-plans, and env
steps per second counting only ``env.step`` and overall (expert, planning and resets too).
Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from hispo_pl.envs import make_env
from hispo_pl.envs.videogame.expert import GameExpert
from hispo_pl.envs.videogame.layouts import AMAZEVILLE_NAMES, SIMPLETOWN_NAMES

ALL_MAZES = tuple(f"amazeville-{m}" for m in AMAZEVILLE_NAMES) + tuple(
    f"simpletown-{m}" for m in SIMPLETOWN_NAMES
)


def run_maze(task: str, episodes: int, seed: int, perfect: bool = False) -> dict:
    """Run ``episodes`` seeded episodes of the expert on ``task``; timings and outcomes."""
    env = make_env(task)
    expert = GameExpert(env, perfect=perfect)
    layout = env.unwrapped.layout
    successes, lengths, replans, failures = 0, [], [], []
    step_time = plan_time = 0.0
    steps = 0
    t_all = time.perf_counter()
    for k in range(episodes):
        rng = np.random.default_rng([seed, k])
        start, goal = layout.sample_start_goal(rng)
        obs, _ = env.reset(seed=seed * 1_000_003 + k, options={"start": start, "goal": goal})
        expert.reset(rng)
        ok = False
        n = 0
        while True:
            action = expert.act(obs)
            t = time.perf_counter()
            obs, _, terminated, truncated, info = env.step(action)
            step_time += time.perf_counter() - t
            n += 1
            if terminated or truncated:
                ok = bool(info["success"])
                break
        successes += ok
        lengths.append(n)
        replans.append(expert.replans)
        plan_time += expert.plan_seconds
        steps += n
        if not ok:
            failures.append((k, tuple(np.round(start, 1)), tuple(np.round(goal, 1))))
    total = time.perf_counter() - t_all
    env.close()
    return {
        "task": task,
        "episodes": episodes,
        "success": 100.0 * successes / episodes,
        "length": float(np.mean(lengths)),
        "max_length": int(np.max(lengths)),
        "replans": float(np.mean(replans)),
        "env_sps": steps / step_time,
        "all_sps": steps / total,
        "plan_ms": 1000.0 * plan_time / episodes,
        "failures": failures,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=50, help="episodes per maze")
    parser.add_argument("--mazes", nargs="+", default=list(ALL_MAZES), help="tasks to run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--perfect", action="store_true", help="no imperfections (the planner's reference)"
    )
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    head = (
        f"{'maze':<18} {'episodes':>8} {'success %':>9} {'mean len':>8} {'max len':>7} "
        f"{'replans':>7} {'plan ms/ep':>10} {'env steps/s':>11} {'overall steps/s':>15}"
    )
    print(head)
    print("-" * len(head))
    rows = []
    for task in args.mazes:
        r = run_maze(task, args.episodes, args.seed, args.perfect)
        rows.append(r)
        print(
            f"{r['task']:<18} {r['episodes']:>8d} {r['success']:>9.1f} {r['length']:>8.1f} "
            f"{r['max_length']:>7d} {r['replans']:>7.2f} {r['plan_ms']:>10.1f} "
            f"{r['env_sps']:>11.0f} {r['all_sps']:>15.0f}",
            flush=True,
        )
    print("-" * len(head))
    worst = min(rows, key=lambda r: r["success"])
    print(f"lowest success: {worst['task']} {worst['success']:.1f} %")
    for r in rows:
        for k, start, goal in r["failures"]:
            print(f"  failed: {r['task']} episode {k} start {start} goal {goal}")


if __name__ == "__main__":
    main()
