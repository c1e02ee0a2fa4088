"""What a user sees in TensorBoard for a benchmark: every run's scalars, images, texts and
HParams metrics, read back from the event files with TensorBoard's own reader.

    python benchmarks/tensorboard_tags.py results/pointmaze-1

prints, per run (``runs/<method>/seed<S>``), how many tags of each kind it holds, then the
tags common to the runs grouped by their first path component.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator


def run_tags(run_dir: Path) -> dict[str, set[str]]:
    """Scalar, image and text tags of one run directory, and its HParams metric names."""
    acc = EventAccumulator(str(run_dir), size_guidance={"images": 0, "tensors": 0, "scalars": 0})
    acc.Reload()
    tags = acc.Tags()
    hparams = acc.PluginTagToContent("hparams").get("_hparams_/experiment", b"")
    metrics = {
        tag for tag in tags["scalars"] if tag.startswith("stream/") and tag.encode() in hparams
    }
    return {
        "scalars": set(tags["scalars"]),
        "images": set(tags["images"]),
        "texts": {t.removesuffix("/text_summary") for t in tags["tensors"]},
        "hparams metrics": metrics,
    }


def grouped(tags: set[str]) -> str:
    by_group: dict[str, list[str]] = defaultdict(list)
    for tag in sorted(tags):
        by_group[tag.split("/", 1)[0]].append(tag)
    return "\n".join(
        f"    {group}/ ({len(names)}): {', '.join(names[:6])}{' ...' if len(names) > 6 else ''}"
        for group, names in by_group.items()
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="a benchmark's --out folder (its runs/ inside)")
    args = parser.parse_args()
    runs = sorted(p.parent for p in (args.out / "runs").glob("*/seed*/events.out.tfevents.*"))
    runs = sorted(set(runs))
    if not runs:
        raise SystemExit(f"no event files under {args.out / 'runs'}")
    seen = {run: run_tags(run) for run in runs}
    for run, tags in seen.items():
        counts = ", ".join(f"{len(v)} {k}" for k, v in tags.items())
        print(f"{run.relative_to(args.out)}: {counts}")
    for kind in ("scalars", "images", "texts", "hparams metrics"):
        common = set.intersection(*(tags[kind] for tags in seen.values()))
        print(f"\n{kind} in every run ({len(common)}):\n{grouped(common)}")


if __name__ == "__main__":
    main()
