"""Stopping on a signal: SIGTERM (``kill``, a scheduler's stop, the benchmark stopping its
runs) ends a command the way Ctrl-C does, and the request stays until the command stops.

The signal raises ``KeyboardInterrupt`` wherever Python is; raised while Python runs a
finaliser (an object's ``__del__``, a weakref callback), it is printed as "Exception ignored"
and lost. So the request is kept here, and :class:`~hispo_pl.console.StopWhenAsked`, among
every Trainer's callbacks, raises it again at the next training step or task end. (No
Lightning here: ``hispo-pl --help`` imports this module.)"""

from __future__ import annotations

import contextlib
import signal

_received: list[int] = []  # the signals asking the command to stop, while it runs


@contextlib.contextmanager
def terminate_as_interrupt():
    """SIGTERM raises ``KeyboardInterrupt`` while the command runs, and is remembered
    (:func:`stop_requested`): a stream keeps what it finished and says how to resume, a
    benchmark stops its runs. Lightning alone only notes a SIGTERM that arrives during a
    training step, and a stream's next task forgets it. Yields the list the signal's number is
    put in."""

    received: list[int] = []  # the command's, kept after it stops

    def interrupt(signum, frame):
        received.append(signum)
        _received.append(signum)
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not the main thread: leave signals alone
        yield received
        return
    try:
        yield received
    finally:
        signal.signal(signal.SIGTERM, previous)
        _received.clear()


def stop_requested() -> bool:
    """Whether a signal asked the running command to stop."""
    return bool(_received)
