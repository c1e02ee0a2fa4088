"""One SIGTERM, sent at a random moment, always stops a stream cleanly: exit 143, a line that
says how to resume, no "Exception ignored" and no traceback, and a run directory a rerun
resumes to the uninterrupted run's results.

A scheduler sends one SIGTERM and waits; it may land anywhere: in a training step, in an
atomic save, in a finaliser (``__del__``, where Python would print and drop the interrupt), in
the task-end rollouts, while the stream writes its results. One Python process imports
hispo-pl once and forks a real ``hispo-pl fit`` process per trial (a fresh interpreter per
trial would spend most of the time budget importing torch); each trial runs to its own exit
and interpreter shutdown. Set ``HISPO_PL_SIGNAL_SEED`` to replay a sequence of delays,
``HISPO_PL_SIGNAL_SECONDS`` to try for longer."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time

import pytest
from helpers import ROOT, tiny_stream_args
from probes import stream_dir

from hispo_pl.modules.checkpoints import read_checkpoint
from hispo_pl.rundir import RunDir

# every moment a stop can land is made common: a finaliser that takes a while at every
# training step, in every checkpoint save and in the task-end rollouts; saves at every step
FINALISERS = """
import time
import lightning
from hispo_pl.evaluation import RolloutEvaluator
from hispo_pl.modules.hbc import GoalConditionedBC

class _Finalised:
    def __del__(self):
        time.sleep(0.05)

def _with_a_finaliser(function):
    def wrapped(*args, **kwargs):
        _Finalised()  # collected at once: its __del__ runs here
        return function(*args, **kwargs)
    return wrapped

import sys
import hispo_pl.stopping as stopping
_again = stopping._deliver_again
def _counted():
    print("[probe] a finaliser dropped the stop; delivered again", file=sys.stderr, flush=True)
    _again()
stopping._deliver_again = _counted

GoalConditionedBC.training_step = _with_a_finaliser(GoalConditionedBC.training_step)
lightning.Trainer.save_checkpoint = _with_a_finaliser(lightning.Trainer.save_checkpoint)
RolloutEvaluator.run = _with_a_finaliser(RolloutEvaluator.run)
"""

# imports hispo-pl once, then per request "FOLDER OUTPUT DELAY" forks a fit into FOLDER (its
# output to the file OUTPUT), sends it SIGTERM after DELAY seconds (none: never) unless it ended
# first, and answers with a JSON line
SERVER = """
import json, os, signal, sys, time
sys.argv = ["hispo-pl"]
from hispo_pl.cli import main
import hispo_pl.callbacks, hispo_pl.cli_stream, hispo_pl.fit, hispo_pl.loop  # imported once
{prelude}
ARGS = {args!r}

def fit(folder, output):
    out = os.open(output, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    os.dup2(out, 1)
    os.dup2(out, 2)
    code = main([a.replace("@OUT@", folder) for a in ARGS])
    with open(output + ".ended", "w") as f:  # when the command returned (then Python exits)
        f.write(repr(time.monotonic()))
    sys.exit(code)

print("ready", flush=True)
for line in sys.stdin:
    folder, output, delay = line.split()
    sys.stdout.flush()
    pid = os.fork()
    if pid == 0:
        fit(folder, output)
    start, sent, status = time.monotonic(), None, None
    while status is None:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        status = None
        now = time.monotonic() - start
        if sent is None and delay != "none" and now >= float(delay):
            os.kill(pid, signal.SIGTERM)
            sent = now
        time.sleep(0.002)
    seconds = time.monotonic() - start
    ended = output + ".ended"
    returned = float(open(ended).read()) - start if os.path.exists(ended) else None
    report = {{"rc": os.waitstatus_to_exitcode(status), "sent": sent, "s": seconds,
              "returned": returned}}
    print(json.dumps(report), flush=True)
"""

# the signalled trials' share of the test's time (HISPO_PL_SIGNAL_SECONDS: more trials)
TRIALS_SECONDS = float(os.environ.get("HISPO_PL_SIGNAL_SECONDS", "20"))
RESUMES = 1  # stopped runs resumed to the end: those that had gone furthest


class ForkServer:
    """The :data:`SERVER` process: ``run(folder, delay)`` forks one fit and reports it."""

    def __init__(self, args: list[str], prelude: str):
        source = SERVER.format(prelude=prelude, args=args)
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, "-c", source],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
            cwd=ROOT,
        )
        assert self.proc.stdout.readline().strip() == "ready"

    def run(self, folder, delay: float | None = None, output: str = "output") -> dict:
        """A fit into ``folder`` (made if missing), stopped after ``delay`` seconds (None:
        never); its exit code, when the signal was sent, its duration and its output."""
        folder.mkdir(parents=True, exist_ok=True)
        when = "none" if delay is None else delay
        self.proc.stdin.write(f"{folder} {folder / output} {when}\n")
        self.proc.stdin.flush()
        report = json.loads(self.proc.stdout.readline())
        report["output"] = (folder / output).read_text()
        return report

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=30)


def _resumable_state(run_dir) -> int:
    """The tasks a rerun would skip, after checking that every file it reads is whole."""
    run = RunDir(run_dir)
    assert not list(run.path.glob(".*tmp")), "a save left its scratch file"
    progress = run.read_progress() if run.path.is_dir() else None
    done = progress.done if progress is not None else 0
    for k in range(done):
        read_checkpoint(run.checkpoint(k))
    for partial in run.path.glob("*.partial.ckpt"):
        read_checkpoint(partial)
    return done


@pytest.mark.e2e
def test_one_sigterm_at_a_random_moment_always_stops_the_stream_cleanly(tiny_umaze, tmp_path):
    seed = int(os.environ.get("HISPO_PL_SIGNAL_SEED", random.randrange(10**6)))
    rng = random.Random(seed)
    extra = ["--checkpoint_every", "1", "--trainer.max_steps", "4"]
    server = ForkServer([*tiny_stream_args("ftn", "@OUT@"), *extra], FINALISERS)
    try:
        whole = server.run(tmp_path / "whole")
        assert whole["rc"] == 0, whole["output"][-3000:]
        reference = json.loads((stream_dir(tmp_path / "whole") / "results.json").read_text())
        # from the fork to a little after the command returned (Python then exits)
        length, trials, states = 1.1 * whole["returned"], [], {}
        end = time.monotonic() + TRIALS_SECONDS
        while time.monotonic() < end:
            folder = tmp_path / f"t{len(trials)}"
            delay = round(rng.uniform(0, length), 3)
            report = {**server.run(folder, delay), "delay": delay, "folder": folder}
            trials.append(report)
            said = f"(seed {seed}, trial {len(trials) - 1}, SIGTERM after {delay} s)"
            out, rc = report["output"], report["rc"]
            assert "Exception ignored" not in out and "Traceback" not in out, f"{said}\n{out}"
            run_dir = stream_dir(folder)
            finished = (run_dir / "results.json").exists()
            if rc == 128 + signal.SIGTERM:
                assert "rerun the same command" in out.lower(), f"{said}\n{out}"
            else:  # the signal came as the fit was ending: it must have ended whole
                assert rc in (0, -signal.SIGTERM) and finished, f"{said} exit {rc}\n{out}"
            state = (_resumable_state(run_dir), bool(list(run_dir.glob("*.partial.ckpt"))))
            states.setdefault(state, folder)
        codes = [t["rc"] for t in trials]
        dropped = sum("a finaliser dropped the stop" in t["output"] for t in trials)
        print(
            f"seed {seed}: {len(trials)} trials, exits {codes}, {dropped} stops dropped by a "
            f"finaliser, states {sorted(states)}"
        )
        assert codes.count(128 + signal.SIGTERM) >= len(trials) // 2, codes
        # stopped runs resume to the uninterrupted run's results (each state a rerun starts
        # from, tasks finished and a task saved part-way, was checked readable above)
        unfinished = sorted(state for state in states if state[0] < 2)
        for state in unfinished[-RESUMES:]:
            folder = states[state]
            resumed = server.run(folder, output="resumed")
            assert resumed["rc"] == 0, resumed["output"][-3000:]
            results = json.loads((stream_dir(folder) / "results.json").read_text())
            for key in ("R", "PER", "BWT", "stored_bytes"):
                assert results[key] == reference[key], (state, key)
    finally:
        server.close()


def test_a_stop_an_import_wrapped_in_its_own_error_stops_the_fit(tiny_umaze):
    """A SIGTERM landing while a C extension initialises (``import mujoco`` at a task's first
    evaluation) comes out as ``ImportError: initialization failed`` caused by the interrupt:
    the fit stops as on any stop, with no traceback."""
    import lightning as L
    from helpers import quiet_trainer

    from hispo_pl.config import BackboneConfig
    from hispo_pl.data.datamodule import TaskDataModule
    from hispo_pl.loop import fit_interruptibly
    from hispo_pl.modules import HBC
    from hispo_pl.stopping import signals_stop_the_command

    class StopInsideAnImport(L.Callback):
        def on_train_start(self, trainer, pl_module):
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)
            except KeyboardInterrupt as stop:  # as a C extension's initialisation wraps it
                raise ImportError("initialization failed") from stop

    module = HBC(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16))
    data = TaskDataModule(task="pointmaze-umaze-N[6]", batch_size=16, steps_per_epoch=2)
    trainer = quiet_trainer(4, callbacks=[StopInsideAnImport()])
    with signals_stop_the_command() as received, pytest.raises(KeyboardInterrupt) as stopped:
        fit_interruptibly(trainer, module, data)
    assert received == [signal.SIGTERM] and stopped.value.__cause__ is None


def test_the_command_says_interrupted_for_a_stop_an_import_wrapped(monkeypatch, capsys):
    import hispo_pl.cli as cli

    def wrapped_stop(argv):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        except KeyboardInterrupt as stop:
            raise ImportError("initialization failed") from stop

    monkeypatch.setattr(cli, "_dispatch", wrapped_stop)
    assert cli.main(["data", "list"]) == 128 + signal.SIGTERM
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err


def test_an_error_without_a_stop_behind_it_keeps_its_traceback(monkeypatch):
    import hispo_pl.cli as cli

    def broken(argv):
        raise ImportError("initialization failed")

    monkeypatch.setattr(cli, "_dispatch", broken)
    with pytest.raises(ImportError):
        cli.main(["data", "list"])
