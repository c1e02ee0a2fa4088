"""What a stream prints on a terminal 80 columns wide: a training bar with room for its bar,
no library notice glued to it or repeated, no redraw after the task's search and evaluation,
a model summary without a column that reads 0."""

from __future__ import annotations

import io
import logging
import sys
from types import SimpleNamespace

import pytest
from helpers import TINY_STREAM, load_benchmark, tiny_stream_args
from lightning.pytorch.callbacks import ModelSummary, RichModelSummary
from lightning.pytorch.callbacks.progress.tqdm_progress import Tqdm
from tqdm.utils import disp_len

from hispo_pl.console import (
    MIN_BAR_CELLS,
    ParameterSummary,
    TaskProgressBar,
    fit_postfix,
    parameter_line,
    plain_summary,
    short_metric_name,
)

LOGGED_BAR = ("--trainer.enable_progress_bar", "true", "--trainer.log_every_n_steps", "10")
LOSSES = {
    "task_02/train/loss": 3.86,
    "task_02/train/loss_high": 1.234,
    "task_02/train/loss_low": 2.6,
}


def test_a_long_line_wraps_between_words_on_a_terminal():
    from hispo_pl.console import terminal_line

    line = (
        "[hispo-pl] task 2/2 done in 1m49s (training 1m40s, evaluation 2s, search 7s): "
        "success 100 %"
    )
    wrapped = terminal_line(line, width=80).splitlines()
    assert wrapped == [
        "[hispo-pl] task 2/2 done in 1m49s (training 1m40s, evaluation 2s, search 7s):",
        "           success 100 %",
    ]
    assert terminal_line(line, width=200) == line
    assert terminal_line(line) == line  # not a terminal (pytest's capture): one line, for grep


def test_short_metric_names():
    assert short_metric_name("task_02/train/loss") == "loss"
    assert short_metric_name("task_02/train/loss_high") == "high"
    assert short_metric_name("task_02/train/penalty") == "penalty"
    assert short_metric_name("loss_") == "loss_"


def test_fit_postfix_keeps_the_leading_values_that_fit():
    values = {"loss": "3.860", "high": "1.234", "low": "2.600"}
    assert fit_postfix(values, None) == values
    assert fit_postfix(values, len(", loss=3.860")) == {"loss": "3.860"}
    assert fit_postfix(values, len(", loss=3.860, high=1.234") + 3) == {
        "loss": "3.860",
        "high": "1.234",
    }
    assert fit_postfix(values, 4) == {}


class _Trainer:
    """What the bar reads of a Trainer."""

    def __init__(self, step: int, max_steps: int = 3000):
        self.global_step, self.max_steps = step, max_steps
        self.progress_bar_metrics = dict(LOSSES)
        self.loggers = [SimpleNamespace(version="seed0")]


def _bar_at(columns: int, step: int, max_steps: int = 3000) -> tuple[TaskProgressBar, io.StringIO]:
    out = io.StringIO()
    callback = TaskProgressBar("task 2/2")
    bar = Tqdm(total=max_steps, desc="task 2/2", ncols=columns, file=out, smoothing=0,
               bar_format=TaskProgressBar.BAR_FORMAT)  # fmt: skip
    callback.train_progress_bar = bar
    bar.n = step
    bar.start_t -= step / 38.6  # a task's pace on a CPU: 38.6 steps/s so far
    return callback, out


@pytest.mark.parametrize("columns, shown", [(80, ["loss"]), (120, ["loss", "high", "low"])])
def test_the_training_bar_fits_its_values_to_the_terminal(columns, shown):
    callback, _ = _bar_at(columns, 2700)
    callback.show_metrics(_Trainer(2700), None)
    line = str(callback.train_progress_bar)
    assert disp_len(line) <= columns
    assert len(line.split("|")[1]) >= MIN_BAR_CELLS  # the bar itself, not one cell
    assert _postfix(line) == shown
    assert "task_02/train" not in line and "v_num" not in line


def _postfix(line: str) -> list[str]:
    """The names of a bar line's values (after its rate)."""
    tail = line.rsplit("it/s", 1)[1].strip(", ]")
    return [part.split("=")[0] for part in tail.split(", ") if part]


def test_the_bar_ends_with_the_training_and_is_not_redrawn_after():
    callback, out = _bar_at(80, 2990, max_steps=3000)
    callback.on_train_batch_end(_Trainer(3000, 3000), None, None, None, 0)
    ended = out.getvalue()
    assert "3000/3000" in ended.splitlines()[-1] and ended.endswith("\n")  # kept, on its line
    # the search and evaluation run in the task's on_train_end hooks; Lightning closes the bar
    # at its own on_train_end, after them: nothing is drawn again (with the slower rate)
    callback.on_train_epoch_end(_Trainer(3000, 3000), None)
    callback.on_train_end()
    assert out.getvalue() == ended


def test_lightnings_notice_of_a_reached_budget_is_not_printed(caplog):
    from lightning.pytorch.utilities.rank_zero import rank_zero_info

    from hispo_pl.cli import _quiet_known_warnings

    _quiet_known_warnings()
    # the logger's own level too: a script another test ran in this process may have set it
    with caplog.at_level(logging.INFO, logger="lightning.pytorch.utilities.rank_zero"):
        rank_zero_info("`Trainer.fit` stopped: `max_steps=3000` reached.")
        rank_zero_info("`Trainer.fit` stopped: No training batches.")
    messages = [r.getMessage() for r in caplog.records]
    assert messages == ["`Trainer.fit` stopped: No training batches."]


def test_the_model_summary_is_one_line_without_flops(tiny_umaze):
    from helpers import tiny_hispo

    line = parameter_line("HiSPO", tiny_hispo())
    assert line.startswith("HiSPO: ") and " parameters (" in line and " MB)" in line
    assert "policies" in line and "FLOP" not in line
    mine = ParameterSummary()
    kept = [mine, RichModelSummary(), ModelSummary(), "other"]
    swapped = plain_summary(kept)
    assert swapped[0] is mine and swapped[3] == "other"
    assert [type(cb) for cb in swapped[:3]] == [ParameterSummary] * 3


@pytest.mark.e2e
def test_a_stream_on_an_80_column_terminal(tiny_umaze, tmp_path):
    """The whole stream in a pseudo-terminal, as a user's screen shows it."""
    capture = load_benchmark("terminal_capture")
    args = tiny_stream_args("hispo", tmp_path, TINY_STREAM, *LOGGED_BAR)
    args[args.index("--trainer.max_steps") + 1] = "30"
    text = capture.run_in_terminal([sys.executable, "-m", "hispo_pl.cli", *args], 80)
    screen = capture.render(text, 80)
    joined = "\n".join(screen)
    assert "[hispo-pl] PER" in joined, joined
    assert joined.count("GPU available") <= 1
    assert "Trainer.fit" not in joined and "FLOP" not in joined
    bars = [line for line in screen if line.startswith("task ") and "|" in line]
    assert [b.split(":")[0] for b in bars] == ["task 1/2", "task 2/2"]  # one each, as it ended
    for bar in bars:
        assert "30/30" in bar and "loss=" in bar and "train/" not in bar
        assert len(bar.split("|")[1]) >= MIN_BAR_CELLS


def test_the_capture_replays_what_a_terminal_shows():
    capture = load_benchmark("terminal_capture")
    assert capture.render("abc\rX\n", 80) == ["Xbc"]
    assert capture.render("one\r\ntwo\x1b[A\rONE\r\n", 80) == ["ONE", "two"]
    assert capture.render("abcdef", 4) == ["abcd", "ef"]
    assert capture.render("\x1b[1mbold\x1b[0m and\x1b[K", 80) == ["bold and"]
    assert capture.render("abcdef\r\x1b[2Kxy", 80) == ["xy"]
