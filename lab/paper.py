"""The paper's own figures (``paper.yaml`` beside this file), as the tables beside ours read
them: per stream and method the ``(mean, std)`` of PER, BWT, FWT and MEM (its Tables 7–9), its
Table 1 aggregate and its Table 2 AntMaze ablation."""

from __future__ import annotations

from pathlib import Path

import yaml

Stat = tuple[float, float]  # mean, std as the paper prints them

_DATA = yaml.safe_load((Path(__file__).with_name("paper.yaml")).read_text())

METRICS: tuple[str, ...] = tuple(_DATA["metrics"])
# stream -> method -> (PER, BWT, FWT, MEM)
PER_STREAM: dict[str, dict[str, tuple[Stat, ...]]] = {
    stream: {method: tuple(tuple(v) for v in values) for method, values in table.items()}
    for stream, table in _DATA["per_stream"].items()
}
# Table 1: method -> (PER, BWT, FWT)
AGGREGATE: dict[str, tuple[float, float, float]] = {
    method: tuple(values) for method, values in _DATA["aggregate"].items()
}
# Table 2: method -> (PER, MEM)
ANTMAZE_ABLATION: dict[str, tuple[Stat, Stat]] = {
    method: tuple(tuple(v) for v in values) for method, values in _DATA["antmaze_ablation"].items()
}


def paper_row(stream: str, method: str) -> dict[str, Stat] | None:
    """The paper's (mean, std) of each metric for ``method`` on ``stream``; None if it has
    none (it ran no CSP, CSPO or HiLOW per stream)."""
    values = PER_STREAM.get(stream, {}).get(method)
    return None if values is None else dict(zip(METRICS, values, strict=True))


def mean_per(method: str, streams: list[str]) -> float | None:
    """The paper's PER of ``method`` averaged over ``streams`` (its per-stream tables): its
    figure on exactly the streams a row of ours covers. ``None`` where a stream lacks it."""
    return mean_of("PER", method, streams)


def mean_of(metric: str, method: str, streams: list[str]) -> float | None:
    """The paper's ``metric`` of ``method`` averaged over ``streams`` (its per-stream tables);
    ``None`` where a stream lacks it."""
    rows = [paper_row(stream, method) for stream in streams]
    if not rows or any(row is None for row in rows):
        return None
    return sum(row[metric][0] for row in rows) / len(rows)
