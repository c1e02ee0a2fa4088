"""Summarise finished stream runs (their ``results.json``) per run and as mean ± std.

    python benchmarks/stream_summary.py runs/pointmaze-1/seed0 runs/pointmaze-1/seed1 ...

PER, BWT, FWT in points (×100, like the paper), MEM as a ratio, anchors per subspace, and the
wall time of the stream.
"""

from __future__ import annotations

import sys

from hispo_pl.metrics import summarize_runs
from hispo_pl.rundir import RunDir

SCALE = {"PER": 100, "BWT": 100, "FWT": 100, "MEM": 1, "minutes": 1}


def main(run_dirs: list[str]) -> None:
    results = []
    for d in run_dirs:
        run = RunDir(d)
        if not run.results_file.exists():
            sys.exit(
                f"{run.results_file} not found: is the run finished? (rerun its command to "
                "resume it)"
            )
        r = run.read_results()
        results.append(r)
        anchors = " ".join(f"{k}={v}" for k, v in r.get("anchors", {}).items())
        print(
            f"{d}: PER {100 * r['PER']:.1f}  BWT {100 * r['BWT']:.1f}  MEM {r['MEM']:.2f}  "
            f"anchors {anchors}  {sum(r['wall_time_s']) / 60:.1f} min"
        )
    summary = summarize_runs(results)
    print(
        f"mean ± std over {len(results)} runs: "
        + "  ".join(
            f"{k} {SCALE[k] * m:.1f} ± {SCALE[k] * s:.1f}"
            if k != "MEM"
            else f"{k} {m:.2f} ± {s:.2f}"
            for k, (m, s) in summary.items()
        )
    )


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
