"""One progress policy for every long step: data generation, training, the rollout evaluation
and the search at a task's end, ``hispo-pl evaluate``. On a terminal a bar redraws in place;
in a log or a pipe a line is printed at every tenth of the work, never a carriage return.
Progress goes to stderr, so that stdout keeps what a command prints as its result (the JSON
of ``data generate``, ``evaluate --json``)."""

from __future__ import annotations

import sys
import time

from tqdm import tqdm


def interactive() -> bool:
    """Whether a bar can redraw in place: stdout and stderr are both terminals (a bar written
    into a redirected stream is one long line of carriage returns)."""
    return sys.stdout.isatty() and sys.stderr.isatty()


def duration(seconds: float) -> str:
    """``4m07s``, ``52s``, ``1h02m``."""
    s = round(seconds)
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


def tenth_marks(total: int) -> list[int]:
    """The counts at which a line is printed: each tenth of ``total`` (every count when there
    are fewer than ten), the last one included."""
    if total <= 0:
        return []
    return sorted({max(1, -(-total * i // 10)) for i in range(1, 11)})


class ProgressPrinter:
    """Counts ``total`` units of work under ``label``; a bar on a terminal, else a line at each
    tenth (``[hispo-pl] eval pointmaze-umaze-N: 30/100 episodes (30 %), 4s``). Disabled, it
    prints nothing. Use as a context manager, or call :meth:`close`.

    Example::

        with ProgressPrinter(f"collecting {name}", episodes, "episodes") as collecting:
            for k in range(episodes):
                ...  # one episode
                collecting.update()
    """

    def __init__(
        self,
        label: str,
        total: int,
        unit: str = "",
        enabled: bool = True,
        bar: bool | None = None,
        file=None,
    ):
        self.label, self.total, self.unit = label, total, unit
        self.enabled = enabled and total > 0
        self.count = 0
        self._file = file
        self._start = time.perf_counter()
        self._marks = set(tenth_marks(total))
        use_bar = interactive() if bar is None else bar
        self._bar = (
            tqdm(total=total, desc=label, unit=unit or "it", leave=False, file=self.file)
            if self.enabled and use_bar
            else None
        )

    @property
    def file(self):
        return self._file if self._file is not None else sys.stderr

    def update(self, n: int = 1) -> None:
        if not self.enabled:
            return
        before, self.count = self.count, min(self.count + n, self.total)
        if self._bar is not None:
            self._bar.update(self.count - before)
        elif any(before < m <= self.count for m in self._marks):
            self.file.write(self.line() + "\n")
            self.file.flush()

    def write(self, text: str) -> None:
        """Print ``text`` to stdout as a line of its own, above the bar when there is one."""
        if self._bar is not None:
            self._bar.write(text, file=sys.stdout)
        else:
            print(text, flush=True)

    def line(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        share = 100 * self.count / self.total
        seconds = duration(time.perf_counter() - self._start)
        return (
            f"[hispo-pl] {self.label}: {self.count}/{self.total}{unit} ({share:.0f} %), {seconds}"
        )

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> ProgressPrinter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
