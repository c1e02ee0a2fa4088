"""Shared fixtures: an isolated Minari store, one torch thread by default
(``HISPO_PL_TEST_THREADS``), one tiny generated PointMaze dataset and one finished tiny
stream."""

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


@pytest.fixture(autouse=True)
def _session_datasets_stay_tiny(minari_home):
    """Fail the test that left one of our expert datasets (a user's own may be of any size) of
    more than a few episodes in the session's store: a fit whose tiny tasks find no data
    generates it at the family's default size (500 episodes), slowly, and every later
    ``tiny_umaze`` on that worker then meets a dataset it did not make. Such a test asks for
    ``tiny_umaze`` first. The dataset is removed, so only its maker fails."""
    import json
    import shutil

    from hispo_pl.data.datasets import NAMESPACE

    yield
    for meta in minari_home.glob(f"{NAMESPACE}/*/data/metadata.json"):
        episodes = json.loads(meta.read_text()).get("total_episodes", 0)
        if episodes > TINY_EPISODES:
            dataset = meta.parent.parent
            shutil.rmtree(dataset)
            pytest.fail(
                f"this test generated {dataset.relative_to(minari_home)} at {episodes} episodes "
                "in the session's Minari store; request the tiny_umaze fixture before fitting"
            )


@pytest.fixture(scope="session")
def tiny_umaze(minari_home):
    """A 6-episode local pointmaze-umaze dataset, generated once, as EpisodeArrays."""
    from hispo_pl.data.datasets import load_episodes
    from hispo_pl.data.generation import generate_dataset

    assert os.environ["MINARI_DATASETS_PATH"] == str(minari_home)
    generate_dataset("pointmaze-umaze", episodes=TINY_EPISODES, progress=False)
    return load_episodes(f"pointmaze-umaze-N[{TINY_EPISODES}]")


@pytest.fixture(scope="session", autouse=True)
def _suite_threads():
    """One torch thread for the whole session, set before any fixture builds a model: tiny
    networks on a 2-core machine run many times faster without intra-op threads competing for
    the cores. ``HISPO_PL_TEST_THREADS=N`` runs the suite at N threads instead (0: the count
    torch picks), to check that no result depends on it. A test that wants more threads sets
    them itself (``torch.set_num_threads``, ``--num_threads``); :func:`_restore_threads`
    undoes it."""
    import torch

    before = torch.get_num_threads()
    threads = int(os.environ.get("HISPO_PL_TEST_THREADS", "1"))
    if threads > 0:
        torch.set_num_threads(threads)
    yield
    torch.set_num_threads(before)


@pytest.fixture(autouse=True)
def _restore_threads(_suite_threads):
    """After each test, the thread count it started with (one), whatever the test set: a
    ``hispo-pl fit --num_threads 2`` inside a test leaves torch at two threads otherwise."""
    import torch

    before = torch.get_num_threads()
    yield
    if torch.get_num_threads() != before:
        torch.set_num_threads(before)


@pytest.fixture(scope="session")
def tiny_run(tiny_umaze, tmp_path_factory):
    """A finished two-task FTN stream (tiny budgets): results and run dir."""
    from helpers import fit_tiny_stream

    return fit_tiny_stream("ftn", tmp_path_factory.mktemp("tiny_run"))
