"""Summarise finished stream runs (their ``results.json``) per run and as mean ± std.

    python benchmarks/stream_summary.py runs/pointmaze-1/seed0 runs/pointmaze-1/seed1 ...

PER, BWT, FWT in points (×100, like the paper), MEM as a ratio, anchors per subspace, and the
wall time of the stream.
"""

from __future__ import annotations

import sys

from hispo_pl.metrics import METRIC
from hispo_pl.results import summarize_runs
from hispo_pl.rundir import RunDir


def _metric(name: str, value: float) -> str:
    return METRIC[name].format(value) if name in METRIC else f"{value:.1f}"  # minutes


def main(run_dirs: list[str]) -> None:
    runs = []
    for d in run_dirs:
        run = RunDir(d)
        if not run.has_results():
            sys.exit(
                f"{run.results_file} not found: is the run finished? (rerun its command to "
                "resume it)"
            )
        r = run.stream_results()
        runs.append(r)
        metrics = "  ".join(f"{k} {_metric(k, v)}" for k, v in r.metrics.items())
        anchors = " ".join(f"{k}={v}" for k, v in (r.anchors or {}).items())
        minutes = f"  {sum(r.wall_time_s) / 60:.1f} min" if r.wall_time_s else ""
        print(f"{d}: {metrics}  anchors {anchors}{minutes}")
    summary = summarize_runs(runs)
    print(
        f"mean ± std over {len(runs)} runs: "
        + "  ".join(f"{k} {_metric(k, m)} ± {_metric(k, s)}" for k, (m, s) in summary.items())
    )


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
