"""Shared fixtures: an isolated Minari store, one torch thread by default, one tiny generated
PointMaze dataset and one finished tiny stream."""

from __future__ import annotations

import os

import pytest

TINY_EPISODES = 6


@pytest.fixture(scope="session", autouse=True)
def minari_home(tmp_path_factory):
    """Point MINARI_DATASETS_PATH at a temp dir for the whole session (never ~/.minari).

    minari reads the variable on every call, so setting it here, before any test runs,
    isolates every dataset read, write and listing.
    """
    path = tmp_path_factory.mktemp("minari")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MINARI_DATASETS_PATH", str(path))
        yield path


@pytest.fixture(scope="session")
def tiny_umaze(minari_home):
    """A 6-episode local pointmaze-umaze dataset, generated once, as EpisodeArrays."""
    from hispo_pl.data.datasets import load_episodes
    from hispo_pl.data.generation import generate_dataset

    assert os.environ["MINARI_DATASETS_PATH"] == str(minari_home)
    generate_dataset("pointmaze-umaze", episodes=TINY_EPISODES, progress=False)
    return load_episodes(f"pointmaze-umaze-N[{TINY_EPISODES}]", generate_if_missing=False)


@pytest.fixture(scope="session", autouse=True)
def _one_thread_session():
    """One torch thread for the whole session, set before any fixture builds a model: tiny
    networks on a 2-core machine run several times (up to ~100x) faster without intra-op
    threads competing for the cores. A test that wants more threads sets them itself
    (``torch.set_num_threads``, ``--num_threads``); :func:`_restore_threads` undoes it."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(autouse=True)
def _restore_threads(_one_thread_session):
    """After each test, the thread count it started with (one), whatever the test set: a
    ``hispo-pl fit --num_threads 2`` inside a test leaves torch at two threads otherwise."""
    import torch

    before = torch.get_num_threads()
    yield
    if torch.get_num_threads() != before:
        torch.set_num_threads(before)


@pytest.fixture(scope="module")
def one_thread(_one_thread_session):
    """The session's default made explicit: a module that names it still runs at one thread."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def tiny_run(tiny_umaze, tmp_path_factory):
    """A finished two-task FTN stream (tiny budgets): results and run dir."""
    from helpers import fit_tiny_stream

    return fit_tiny_stream("ftn", tmp_path_factory.mktemp("tiny_run"))
