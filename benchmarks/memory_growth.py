"""MEM after each task of a long stream for the methods whose memory follows from their
structure (SCN, FTN, PNN), grown from the product's own modules without training
(:mod:`hispo_pl.benchmark.growth`), as a markdown table:

    python benchmarks/memory_growth.py --stream pointmaze-1 --methods scn,ftn,pnn --tasks 12

A random stream (``random-pointmaze-12@0``) takes its family's reference config, as the
benchmark does; the structure does not depend on which tasks the stream holds.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hispo_pl.benchmark.growth import module_for, structural_memory
from hispo_pl.benchmark.plan import stream_config_path
from hispo_pl.config_files import config_root


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stream", default="pointmaze-1")
    parser.add_argument("--methods", default="scn,ftn,pnn")
    parser.add_argument("--tasks", type=int, default=12)
    parser.add_argument("--config-dir", type=Path, default=None)
    args = parser.parse_args(argv)
    config_dir = args.config_dir or config_root()
    stream = stream_config_path(args.stream, config_dir)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    print("| method | " + " | ".join(f"T{k + 1:02d}" for k in range(args.tasks)) + " |")
    print("|---|" + "---:|" * args.tasks)
    for method in methods:
        module = module_for([stream, config_dir / "methods" / f"{method}.yaml"])
        memory = structural_memory(module, args.tasks)
        print(f"| {method} | " + " | ".join(f"{m:.2f}" for m in memory) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
