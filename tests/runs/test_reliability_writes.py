"""Writes, continued from test_reliability.py: what Lightning and the dataset builder write by
name stays in the folder asked (links replaced, never followed), a full disk is one line that
names the file and says "resume" only where a rerun resumes, and a file that is no checkpoint
is called what it is. Real files, links, tmpfs mounts and the ``hispo-pl`` command."""

from __future__ import annotations

import errno
import json
import os
import random
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import ROOT, error_lines, tiny_stream_args

from hispo_pl.cli import main

# --- links where Lightning and the dataset builder write by name -----------------------------


def _dangling_link(link: Path, target: Path) -> Path:
    """A link at ``link`` to ``target``, a file that does not exist: whoever writes through
    the link creates it (Lightning writes ``hparams.yaml`` when no file is there)."""
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(target)
    return target


def _linked_folder(link: Path, outside: Path) -> Path:
    outside.mkdir()
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(outside, target_is_directory=True)
    return outside


def _single_task_args(save_dir: Path) -> list[str]:
    return [
        "fit",
        "--config", str(ROOT / "configs/hbc/pointmaze-umaze.yaml"),
        "--data.task", "pointmaze-umaze-N[6]",
        "--data.batch_size", "64",
        "--trainer.max_steps", "3",
        "--trainer.logger.init_args.save_dir", str(save_dir),
        "--trainer.logger.init_args.name", "task",
        "--trainer.logger.init_args.version", "mine",
        "--trainer.callbacks.init_args.eval_every", "0",
        "--trainer.callbacks.init_args.episodes", "2",
        "--trainer.enable_progress_bar", "false",
    ]  # fmt: skip


def test_lightnings_files_in_a_run_folder_replace_links(tiny_umaze, tmp_path, capsys):
    """A run folder named by its version is reused as it is: a link at ``hparams.yaml`` or
    ``checkpoints/`` there would take Lightning's writes out of it."""
    args = _single_task_args(tmp_path / "runs")
    run = tmp_path / "runs" / "task" / "mine"
    created = _dangling_link(run / "hparams.yaml", tmp_path / "created")
    outside = _linked_folder(run / "checkpoints", tmp_path / "outside")
    assert main(args) == 0
    err = capsys.readouterr().err
    assert not created.exists() and not list(outside.iterdir())
    assert (run / "hparams.yaml").is_file() and not (run / "hparams.yaml").is_symlink()
    assert list((run / "checkpoints").glob("*.ckpt")) and not (run / "checkpoints").is_symlink()
    assert f"{run / 'hparams.yaml'} was a symbolic link to {created}" in err


def test_a_streams_hparams_link_is_replaced(tiny_umaze, tmp_path, capsys):
    run = tmp_path / "pointmaze-1" / "seed0"
    created = _dangling_link(run / "hparams.yaml", tmp_path / "created")
    assert main(tiny_stream_args("ftn", tmp_path, ["pointmaze-umaze-N[3]"])) == 0
    assert not created.exists() and not (run / "hparams.yaml").is_symlink()
    assert "was a symbolic link" in capsys.readouterr().err


def test_dataset_generation_replaces_links_under_the_minari_root(tmp_path, monkeypatch):
    """hispo-pl's locks, staged episodes and builds under the Minari root, and the
    namespace's metadata, are written there: links on the way are replaced."""
    from hispo_pl.data.datasets import load_episodes
    from hispo_pl.data.generation import generate_dataset

    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    locks = _linked_folder(root / ".locks", tmp_path / "locks")
    staging = _linked_folder(root / ".staging", tmp_path / "staging")
    created = _dangling_link(root / "hispo" / "namespace_metadata.json", tmp_path / "created")
    generate_dataset("pointmaze-umaze", episodes=2, progress=False)
    assert not list(locks.iterdir()) and not list(staging.iterdir()) and not created.exists()
    assert (root / "hispo" / "namespace_metadata.json").is_file()
    assert load_episodes("pointmaze-umaze-N[2]").n_episodes == 2


def test_a_search_folder_that_is_a_link_is_replaced(tmp_path):
    from hispo_pl.rundir import RunDir

    run = RunDir(tmp_path / "run")
    outside = _linked_folder(run.path / RunDir.SEARCH, tmp_path / "outside")
    run.write_search(0, "low", losses=np.zeros(2))
    assert not list(outside.iterdir()) and not (run.path / RunDir.SEARCH).is_symlink()
    assert run.read_searches()[(0, "low")]["losses"].tolist() == [0.0, 0.0]


# --- a full disk: one line naming the file; "resume" only where a rerun resumes ---------------


@pytest.fixture
def full_disk(tmp_path):
    """A 2 MB tmpfs (root only), filled to the last byte."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if os.getuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(disk)])
    if done.returncode != 0:
        pytest.skip("tmpfs cannot be mounted here")
    fd = os.open(disk / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        while True:
            os.write(fd, b"\0" * 65536)
    except OSError as err:
        assert err.errno == errno.ENOSPC
    try:
        while True:
            os.write(fd, b"\0")
    except OSError:
        pass
    os.close(fd)
    yield disk
    subprocess.run(["umount", "-l", str(disk)], check=False)


def _finished_benchmark(out: Path) -> None:
    run = out / "runs" / "scn" / "seed0"
    run.mkdir(parents=True)
    tasks = ["pointmaze-umaze-N[500]", "pointmaze-large-N[500]"]
    tasks += ["pointmaze-umaze-PO[500]", "pointmaze-medium-IO[500]"]
    R = [[0.9 if j <= i else None for j in range(4)] for i in range(4)]
    (run / "results.json").write_text(json.dumps({"stream": tasks, "R": R, "MEM": 1.0}))
    (run / "run.json").write_text(json.dumps({"method": "scn", "seed": 0, "stream": "pointmaze-1"}))


@pytest.mark.parametrize(
    "argv, named, resumes",
    [
        (["data", "generate", "pointmaze-umaze", "--episodes", "2"], "minari/", True),
        (["render", "pointmaze-umaze", "--out", "{disk}/m.png"], "m.png", False),
        (["config", "copy", "{disk}/configs"], "configs/", False),
        (
            ["benchmark", "--report-only", "--out", "{tmp}/out", "--export", "{disk}/dest"],
            "dest/scn/seed0/",
            False,
        ),
        (_single_task_args(Path("{disk}/runs")), "runs/task/mine", False),
        (tiny_stream_args("ftn", Path("{disk}/runs")), "runs/pointmaze-1/seed0/", True),
    ],
    ids=["data-generate", "render", "config-copy", "export", "fit-task", "fit-stream"],
)
def test_a_full_disk_is_one_line_naming_the_file(
    tiny_umaze, full_disk, tmp_path, monkeypatch, capsys, argv, named, resumes
):
    if argv[0] == "data":  # else the data read is the tiny one, not on the full disk
        monkeypatch.setenv("MINARI_DATASETS_PATH", str(full_disk / "minari"))
    _finished_benchmark(tmp_path / "out")
    argv = [a.replace("{disk}", str(full_disk)).replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    said = error_lines(err)
    assert len(said) == 1 and "Traceback" not in err and "Exception" not in err, err
    assert f"cannot use {full_disk}/{named}" in said[0] and "no space is left" in said[0], err
    assert ("rerun the same command to resume" in said[0]) == resumes, err


def test_an_error_of_the_disk_without_a_path_is_given_one(tmp_path, monkeypatch, capsys):
    """Where no tmpfs can be mounted: numpy's writer, like TensorBoard's and HDF5's, raises a
    full disk without the file's name."""
    import hispo_pl.data.generation as generation

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))

    def full(file, **arrays):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(generation.np, "savez", full)
    assert main(["data", "generate", "pointmaze-umaze", "--episodes", "2"]) == 2
    said = error_lines(capsys.readouterr().err)
    staged = tmp_path / ".staging" / "pointmaze-umaze-seed0-noise0.2" / "ep_00000.npz"
    assert len(said) == 1 and said[0].startswith(f"hispo-pl data: error: cannot use {staged}:")
    assert "rerun the same command to resume" in said[0]


# --- a file that is no checkpoint is called so ------------------------------------------------


NOISE = random.Random(0).randbytes(4095)


@pytest.mark.parametrize(
    "content, said",
    [
        (b"\x00" + NOISE, "its bytes are not a pickle"),
        # first bytes the unpickler reads as an opcode that then trips on the noise: an
        # undecodable string (MARK, GLOBAL), an empty stack (EMPTY_TUPLE), a pickle "protocol"
        *[(bytes([first]) + NOISE, "its bytes are not a pickle") for first in b"(c)\x80"],
        (b"hello world", "its bytes are not a pickle"),
        (b"\x80\x02}q\x00", "its bytes are not a pickle"),  # a pickle cut short
        (b"", "the file is empty"),
    ],
    ids=["noise", "mark", "global", "empty-tuple", "protocol", "text", "truncated", "empty"],
)
def test_bytes_that_are_no_checkpoint_are_called_so(tmp_path, capsys, content, said):
    path = tmp_path / "x.ckpt"
    path.write_bytes(content)
    with warnings.catch_warnings(record=True) as warned:
        warnings.simplefilter("always")
        assert main(["evaluate", "--ckpt", str(path), "--task", "pointmaze-umaze"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"not a readable hispo-pl checkpoint: {path} (corrupt" in err and said in err, err
    assert "Python objects" not in err and len(err.splitlines()) == 1
    assert not [w for w in warned if "pickle" in str(w.message)]
