"""Expert data collection: our experts roll out in the maze envs, each finished episode is
staged to disk (so a killed run resumes with identical data), and the episodes are written as
one Minari dataset that is moved into place only when complete."""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import shutil
from pathlib import Path

import numpy as np

from ..envs import make_env
from ..envs.family import family_behaviour
from ..errors import ResumableWork, UserError
from ..io import (
    atomic_save,
    atomic_write_text,
    copy_files,
    named_errors,
    open_append,
    real_folder,
    remove_tree,
)
from ..progress import ProgressPrinter
from ..tasks import Task, parse_task
from .datasets import (
    NAMESPACE,
    dataset_exists,
    dataset_path,
    dataset_problem,
    dataset_source,
    default_episodes,
    local_dataset_id,
)

DEFAULT_SEED = 0


@contextlib.contextmanager
def _minari_root(path: Path):
    """Minari's datasets root (``MINARI_DATASETS_PATH``, read on every call) set to ``path``."""
    before = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = before


def _goal_stats(goals: np.ndarray, reached: np.ndarray, limit: int) -> tuple[int, int]:
    """Goals reached, and goals failed (not reached within ``limit`` steps of being set, with
    that deadline inside the episode); goals whose deadline falls after the cut are undecided."""
    changes = np.flatnonzero(np.any(goals[1:] != goals[:-1], axis=-1)) + 1
    starts = np.concatenate([[0], changes])
    n_steps = len(reached)
    ok = failed = 0
    for s in starts:
        window = reached[s : min(s + limit, n_steps)]
        if window.any():
            ok += 1
        elif s + limit <= n_steps:
            failed += 1
    return ok, failed


def expert_class(name: str | Task) -> type:
    """The expert class of a maze's family (its class attributes hold the collection noise).
    Imported here, when data are made, so that reading data never imports an expert."""
    module, _, cls = parse_task(name).env_family.expert.partition(":")
    return getattr(importlib.import_module(module), cls)


def make_expert(name: str, env, expert_weights: str | None = None):
    """The expert of a dataset family (``expert_weights``: the ant policy's file)."""
    cls = expert_class(name)
    if parse_task(name).env_family.expert_reads_weights:
        return cls(env, expert_weights)
    return cls(env)


class DatasetSettingsError(UserError, ValueError):
    """A dataset asked for with other settings than the stored one was made with."""


GENERATION_FILE = "hispo_generation.json"  # beside Minari's metadata: how the data were made


def generation_settings(dataset_id: str) -> dict:
    """The settings a stored local dataset was generated with (``episodes``, and ``seed`` and
    ``noise`` for datasets made since they were recorded)."""
    import minari

    path = dataset_path(dataset_id) / GENERATION_FILE
    if path.exists():
        return json.loads(path.read_text())
    return {"episodes": minari.load_dataset(dataset_id).total_episodes}


def settings_conflict(stored: dict, asked: dict) -> str | None:
    """Which of the asked generation settings differ from the stored ones (settings a stored
    dataset did not record are not compared), or None."""
    diffs = [
        f"{key} {stored[key]} (asked: {value})"
        for key, value in asked.items()
        if key in stored and stored[key] != value
    ]
    return ", ".join(diffs) or None


def package_requirements() -> list[str]:
    """Pip-style pins of what reproduces a dataset's environment (Minari's ``requirements``)."""
    from ..packages import DATASET_PACKAGES, installed_version

    versions = {package: installed_version(package) for package in DATASET_PACKAGES}
    return [f"{p}=={v}" if v else p for p, v in versions.items()]


def _swap_in(new: Path, final: Path, old: Path) -> None:
    """Put the complete dataset ``new`` at ``final``, moving the one it replaces to ``old``
    first (a directory cannot be replaced in one rename) and deleting it only afterwards. A
    link at ``final`` or ``old`` is moved or removed itself, never what it points to."""
    remove_tree(old)
    if os.path.lexists(final):
        os.replace(final, old)
    os.replace(new, final)
    remove_tree(old)


def generate_dataset(
    name: str,
    *,
    episodes: int | None = None,
    seed: int = DEFAULT_SEED,
    noise: float | None = None,
    overwrite: bool = False,
    progress: bool = True,
    expert_weights: str | None = None,
) -> str:
    """Collect ``episodes`` expert episodes of maze ``name`` (``pointmaze-umaze``) and store them
    as the Minari dataset ``hispo/<name>-expert-v0``. Returns the dataset id.

    ``noise``: std of the Gaussian action noise in env units (default: the expert's, 0.2 for
    the ball, 0.04 = D4RL's 0.2 before the ant's action scaling). Collection is resumable: each
    episode is seeded by (seed, index) and staged to disk as soon as it is done, so an
    interrupted run continues where it stopped with identical data. The dataset is written
    into a build directory beside the staged episodes and moved into place only once
    complete (with ``overwrite``, the dataset it replaces stays in use until then); an
    incomplete one found in place (:func:`dataset_problem`) is rebuilt.
    """
    task = parse_task(name)
    # a second process waits, then reuses it; the episodes collected are kept for a rerun
    with ResumableWork(), dataset_lock(task.dataset_name, progress):
        return _generate(task, episodes, seed, noise, overwrite, progress, expert_weights)


def generate_missing(source: str | Task) -> None:
    """Make our local dataset of ``source``'s maze (a task or its spec) when it is not stored
    complete, with the episodes the task reads or the maze's default, whichever is more: what
    a fit does before it reads a task's data. A Minari id is left to the reader, which
    downloads it."""
    source = dataset_source(source)
    if isinstance(source, Task) and not dataset_exists(local_dataset_id(source.dataset_name)):
        episodes = max(source.episodes, default_episodes(source))
        generate_dataset(source.dataset_name, episodes=episodes)


@contextlib.contextmanager
def dataset_lock(name: str, say: bool = True):
    """Hold the dataset ``name``'s build lock (``fcntl.flock`` on ``.locks/NAME.lock`` in the
    Minari root): two processes that need the same missing dataset never write it at once.
    Links under the root are replaced, never written through (:func:`_scratch_folder`)."""
    import fcntl

    path = _scratch_folder(".locks") / f"{name}.lock"
    with open_append(path) as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if say:
                print(f"[hispo-pl] waiting for another process that builds {name}", flush=True)
            fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _scratch_folder(*parts: str) -> Path:
    """The folder ``parts`` under the Minari root, where hispo-pl keeps its locks and builds
    datasets: made as real folders, a link on the way replaced (the root itself may be a
    link: it is where the user keeps datasets)."""
    root = dataset_path("")
    return real_folder(root.joinpath(*parts), root)


def _save_episode(path: Path, episode: dict) -> None:
    """One collected episode, written atomically (a kill leaves none or all of it)."""

    def save(tmp: Path) -> None:
        with open(tmp, "xb") as f:  # a file object: np.savez adds .npz to a name
            np.savez(f, **episode)

    atomic_save(path, save)


def _generate(task, episodes, seed, noise, overwrite, progress, expert_weights) -> str:
    import minari
    from minari.data_collector import EpisodeBuffer

    name = task.dataset_name
    dataset_id = local_dataset_id(name)
    final = dataset_path(dataset_id)
    episodes = episodes or default_episodes(task)
    noise = expert_class(task).action_noise if noise is None else noise
    settings = {"episodes": episodes, "seed": seed, "noise": noise}
    problem = dataset_problem(dataset_id)
    if problem is None and not overwrite:
        conflict = settings_conflict(generation_settings(dataset_id), settings)
        if conflict is not None:
            raise DatasetSettingsError(
                f"{dataset_id} already exists with {conflict}; pass --overwrite to replace it, "
                "or leave the settings at the stored ones to use it as it is"
            )
        return dataset_id
    if problem not in (None, "missing"):  # cut short by a kill while it was written
        remove_tree(final)
    # with --overwrite the stored dataset stays usable until the new one is complete
    steps = task.defaults.max_episode_steps
    behaviour = family_behaviour(task)
    env = behaviour.make_collection_env(task)
    expert = make_expert(name, env, expert_weights)
    staging = _scratch_folder(".staging", f"{name}-seed{seed}-noise{noise}")
    ok = failed = flips = kept_steps = 0
    with ProgressPrinter(f"collecting {name}", episodes, "episodes", progress) as collecting:
        for k in range(episodes):
            path = staging / f"ep_{k:05d}.npz"
            if not path.exists():
                rng = np.random.default_rng([seed, k])
                ep_seed = seed * 1_000_003 + k
                ep = behaviour.collect_episode(env, expert, rng, ep_seed, noise, steps)
                _save_episode(path, ep)
            collecting.update()
    buffers = []
    for k in range(episodes):
        ep = dict(np.load(staging / f"ep_{k:05d}.npz"))
        r_ok, r_failed = _goal_stats(ep["desired_goal"][:-1], ep["reached"], steps)
        ok, failed = ok + r_ok, failed + r_failed
        flips += int(ep.get("flipped", False))
        n = len(ep["actions"])
        kept_steps += n
        ended = behaviour.episode_ended(ep)
        buffers.append(
            EpisodeBuffer(
                id=k,
                seed=seed * 1_000_003 + k,
                observations={
                    key: ep[key] for key in ("observation", "achieved_goal", "desired_goal")
                },
                actions=ep["actions"],
                rewards=list(ep["rewards"]),
                terminations=[False] * (n - 1) + [ended],
                truncations=[False] * (n - 1) + [not ended],
            )
        )
    success = ok / max(ok + failed, 1)
    stats = {
        "goals_reached": ok,
        "goals_failed": failed,
        "goal_success": success,
        "episodes_cut_at_flip": flips,
        "steps": kept_steps,
    }
    description = behaviour.describe_dataset(task, expert, settings, stats)
    build = _scratch_folder(".staging", f"build-{name}")  # a killed build is redone
    remove_tree(build)
    # the dataset is written here, then moved into place whole; HDF5's errors name no file
    with _minari_root(build), named_errors(build):
        minari.create_dataset_from_buffers(
            dataset_id=dataset_id,
            buffer=buffers,
            env=env.spec,
            eval_env=make_env(name).spec,
            author_email="hispo-pl@users.noreply.github.com",
            algorithm_name=expert.name,
            author="hispo-pl",
            code_permalink="https://github.com/hispo-pl/hispo-pl",
            description=description,
            requirements=package_requirements(),
        )
        atomic_write_text(build / dataset_id / GENERATION_FILE, json.dumps(settings))
    real_folder(final.parent, dataset_path(""))
    namespace_meta = build / NAMESPACE / "namespace_metadata.json"
    kept = final.parent / namespace_meta.name
    if namespace_meta.exists() and (kept.is_symlink() or not kept.exists()):
        copy_files([(namespace_meta, kept)])
    _swap_in(build / dataset_id, final, dataset_path("") / ".staging" / f"replaced-{name}")
    shutil.rmtree(build, ignore_errors=True)
    shutil.rmtree(staging, ignore_errors=True)
    return dataset_id
