"""MEM after each task: the table a stream's report gets from the runs that recorded it (the
loop's own recording is pinned in tests/cli/test_cli_stream.py, against TensorBoard)."""

from __future__ import annotations

from hispo_pl.benchmark.finished_runs import RunRecord
from hispo_pl.benchmark.tables import memory_markdown
from hispo_pl.results import StreamResults


def _record(method: str, seed: int, memory: list[float | None] | None) -> RunRecord:
    results = StreamResults(stream=["a", "b", "c"], R=[[1.0]], mem_per_task=memory)
    return RunRecord(method, seed, results)


def test_memory_table_is_the_mean_after_each_task_with_its_spread():
    records = [
        _record("hispo", 0, [1.0, 2.0, 2.0]),
        _record("hispo", 1, [1.0, 1.5, 2.5]),
        _record("scn", 0, [1.0, 2.0, 3.0]),
        _record("old", 0, None),  # made before MEM was recorded per task
        _record("resumed", 0, [None, 2.0, 3.0]),  # its first task made by an older run
    ]
    text = memory_markdown(records, "pointmaze-1")
    assert "| hispo | 2 | 1.00 | 1.75 (1.50–2.00) | 2.25 (2.00–2.50) |" in text
    assert "| scn | 1 | 1.00 | 2.00 | 3.00 |" in text
    assert "old" not in text and "resumed" not in text
    assert memory_markdown([_record("old", 0, None)]) == ""
