"""Stopping on a signal: Ctrl-C and SIGTERM (``kill``, a scheduler's stop, the benchmark
stopping its runs) end a command the same way, and the request stays until it stops.

The signal raises ``KeyboardInterrupt`` wherever Python is; raised while Python runs a
finaliser (an object's ``__del__``, a weakref callback), Python drops it and would print
"Exception ignored". So the request is kept here, and a dropped interrupt is not printed but
delivered again a moment later, out of the finaliser, whatever the command is doing (every
verb stops, not only a training step). :class:`~hispo_pl.console.StopWhenAsked`, among every
Trainer's callbacks, also raises it at the next training step or task end. (No Lightning
here: ``hispo-pl --help`` imports this module.)"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

from .errors import Interrupted

STOPS = (signal.SIGINT, signal.SIGTERM)  # Ctrl-C, and kill's or a scheduler's stop
_received: list[int] = []  # the signals asking the command to stop, while it runs
_running = threading.Lock()  # held while the handler is swapped back: no delivery then
AGAIN_AFTER_S = 0.01  # a dropped stop is delivered again after this long


def _deliver_again() -> None:
    """Send the stop a finaliser dropped once more, shortly, from another thread (the
    finaliser may still run now); not after the command ended."""

    def send() -> None:
        with _running:
            if _received:
                os.kill(os.getpid(), _received[0])

    timer = threading.Timer(AGAIN_AFTER_S, send)
    timer.daemon = True
    timer.start()


@contextlib.contextmanager
def signals_stop_the_command():
    """SIGTERM, like Ctrl-C, raises ``KeyboardInterrupt`` while the command runs, and either
    is remembered (:func:`stop_requested`): a stream keeps what it finished and says how to
    resume, a benchmark stops its runs. Lightning alone only notes a SIGTERM that arrives
    during a training step, and a stream's next task forgets it; Python's own Ctrl-C is lost
    when it lands in a finaliser. Yields the list the signal's number is put in."""

    received: list[int] = []  # the command's, kept after it stops

    def interrupt(signum, frame):
        received.append(signum)
        _received.append(signum)
        raise KeyboardInterrupt

    def kept_not_ignored(unraisable) -> None:
        if issubclass(unraisable.exc_type, KeyboardInterrupt) and _received:
            _deliver_again()  # the stop a finaliser dropped: not printed, not lost
            return
        hook(unraisable)

    try:
        previous = {sig: signal.signal(sig, interrupt) for sig in STOPS}
    except ValueError:  # not the main thread: leave signals alone
        yield received
        return
    hook, sys.unraisablehook = sys.unraisablehook, kept_not_ignored
    try:
        yield received
    finally:
        with _running:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            sys.unraisablehook = hook
            _received.clear()


def stop_requested() -> bool:
    """Whether a signal asked the running command to stop."""
    return bool(_received)


def interrupt_behind(err: BaseException) -> bool:
    """Whether a ``KeyboardInterrupt`` is in ``err``'s chain of causes. A stop that lands while
    a C extension initialises (``import mujoco`` at a task's first evaluation) comes out as
    ``ImportError: initialization failed`` caused by the interrupt: that error is the stop
    (or the Ctrl-C).

    Example:
        >>> try:
        ...     try:
        ...         raise KeyboardInterrupt
        ...     except KeyboardInterrupt as stop:
        ...         raise ImportError("initialization failed") from stop
        ... except ImportError as err:
        ...     interrupt_behind(err), interrupt_behind(ValueError())
        (True, False)
    """
    seen: set[int] = set()
    link: BaseException | None = err
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return True
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return False


def stop_exit_code(prog: str, err: BaseException, received: list[int]) -> int | None:
    """The exit code of a command that ``err`` stopped (Ctrl-C, a signal
    :func:`signals_stop_the_command` put in ``received``, or a stop an import wrapped: see
    :func:`interrupt_behind`), after saying so on stderr as ``prog`` (with what was kept, where
    the stop says it); None when ``err`` is not a stop."""
    if not interrupt_behind(err):
        return None
    hint = str(err) if isinstance(err, Interrupted) else "interrupted"
    print(f"\n{prog}: {hint}", file=sys.stderr)
    return 128 + (received[0] if received else signal.SIGINT)
