"""Help answers at once: ``hispo-pl --help`` and the help of the verbs that need no Lightning
to describe themselves import neither Lightning nor torch."""

from __future__ import annotations

import subprocess
import sys

import pytest

PROBE = """
import contextlib, io, sys
from hispo_pl.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        main({argv!r})
    except SystemExit:
        pass
print(sorted(m for m in ("lightning", "torch") if m in sys.modules))
"""


def _heavy_modules_after(argv: list[str]) -> str:
    """The heavy libraries a fresh interpreter holds after ``hispo-pl ARGV``."""
    source = PROBE.format(argv=argv)
    done = subprocess.run(
        [sys.executable, "-c", source], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()[-1]


@pytest.mark.parametrize(
    "argv",
    [[], ["--help"], ["evaluate", "--help"], ["render", "--help"], ["data", "--help"],
     ["config", "--help"], ["config", "list"], ["benchmark", "--help"]],
)  # fmt: skip
def test_help_loads_neither_lightning_nor_torch(argv):
    assert _heavy_modules_after(argv) == "[]"
