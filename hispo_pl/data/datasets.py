"""Expert datasets as real Minari datasets: generated locally by our experts
(:mod:`hispo_pl.data.generation` writes them), or D4RL ids. This module only reads.

Datasets are stored once per maze, in the normal variant; a task's variant is applied to the
arrays at load time by the same pure transforms the env wrapper uses.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import packages
from ..errors import UserError
from ..task_families import FAMILIES
from ..tasks import (
    Task,
    agent_position,
    parse_task,
    reads_as_task_spec,
    transform_action,
    transform_observation,
)

NAMESPACE = "hispo"
DATASET_VERSION = 0


def default_episodes(name: str | Task) -> int:
    """Episodes a maze's dataset holds unless asked otherwise: 500 for PointMaze / AntMaze,
    the paper's 100 (AmazeVille) and 250 (SimpleTown) for the game mazes."""
    return parse_task(name).env_family.default_episodes


class DatasetNotFoundError(UserError, FileNotFoundError):
    """A dataset that is neither stored locally nor downloadable; says how to make one."""


def local_dataset_id(name: str) -> str:
    """Minari id of our local dataset for a maze: ``hispo/pointmaze-umaze-expert-v0``."""
    return f"{NAMESPACE}/{name}-expert-v{DATASET_VERSION}"


# Minari's id grammar: ``[namespace/]name[-v<version>]`` (minari.dataset.minari_dataset)
_MINARI_ID_RE = re.compile(r"^(?:[-\w][-\w/]*[-\w]+/)?[-\w]+?(?:-v\d+)?$")


class DataSourceError(UserError, ValueError):
    """A dataset name that is neither a task spec nor a Minari id."""


def dataset_source(source: str | Task) -> Task | str:
    """What a dataset name means, by one rule: a :class:`Task`, or a string shaped like a task
    spec (``pointmaze-umaze``, ``pointmaze-umaze-PO[100]``), is our local dataset of that maze;
    any other string is a Minari id, which must carry a namespace (``D4RL/pointmaze/umaze-v2``,
    ``mydata/umaze``) or a version (``umaze-v0``). A task spec never ends in ``-v<digits>``
    (its variant is upper case), so the two cannot be confused.

    Raises:
        DataSourceError: neither form (``umaze``, ``my data-v0``).
    """
    if isinstance(source, Task) or reads_as_task_spec(source):
        return parse_task(source)
    text = source.strip()
    if _MINARI_ID_RE.match(text) and ("/" in text or re.search(r"-v\d+$", text)):
        return text
    raise DataSourceError(
        f"{source!r} is neither a task spec nor a Minari dataset id: name a maze's local data "
        "with a task spec (pointmaze-umaze) or a Minari dataset by its id, "
        "[namespace/]name-v<version> (umaze-v0, mydata/umaze-v0, D4RL/pointmaze/umaze-v2)"
    )


def dataset_id_of(source: str | Task) -> str:
    """The Minari id a dataset name reads (:func:`dataset_source`): ours for a task spec."""
    source = dataset_source(source)
    return local_dataset_id(source.dataset_name) if isinstance(source, Task) else source


@dataclass(frozen=True)
class DatasetUse:
    """The dataset a task trains on and how many of its episodes it reads: what a run records
    (``results.json``, ``result.json``, the console), since a task spec's ``[episodes]`` does
    not count a Minari dataset named with ``--data.dataset``."""

    dataset: str  # Minari id
    episodes: int
    # :meth:`EpisodeArrays.content_digest` of the stored episodes, once they are loaded
    digest: str | None = None

    def as_json(self) -> dict:
        used = {"dataset": self.dataset, "episodes": self.episodes}
        return used | ({"digest": self.digest} if self.digest else {})

    def __str__(self) -> str:
        return f"{self.dataset} ({self.episodes} episodes)"


def dataset_path(dataset_id: str) -> Path:
    from minari.storage import get_dataset_path

    return Path(get_dataset_path(dataset_id))


def dataset_problem(dataset_id: str) -> str | None:
    """Why a stored dataset cannot be used (``"missing"``, or what is incomplete about it),
    or None when it is complete: its metadata reads and its HDF5 file opens with as many
    episodes as the metadata says. A dataset cut short by a kill while Minari wrote it thus
    counts as missing rather than as a smaller one."""
    data = dataset_path(dataset_id) / "data"
    if not data.exists():
        return "missing"
    try:
        metadata = json.loads((data / "metadata.json").read_text())
        episodes = int(metadata["total_episodes"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        return f"incomplete: no readable metadata.json ({type(err).__name__})"
    hdf5 = data / "main_data.hdf5"
    if not hdf5.exists():
        if any(data.glob("*.hdf5")) or not any(p.name != "metadata.json" for p in data.iterdir()):
            return "incomplete: no episode data"
        return None  # another Minari storage backend: trust its metadata
    try:
        import h5py

        with h5py.File(hdf5, "r") as f:
            stored = sum(1 for key in f if key.startswith("episode_"))
    except (OSError, ValueError) as err:
        return f"incomplete: {hdf5.name} does not open ({type(err).__name__})"
    if stored != episodes:
        return f"incomplete: {stored} of {episodes} episodes stored"
    return None


def dataset_exists(dataset_id: str) -> bool:
    """Whether the dataset is stored and complete (:func:`dataset_problem`)."""
    return dataset_problem(dataset_id) is None


@dataclass(frozen=True)
class EpisodeArrays:
    """All episodes of a dataset as flat arrays, one row per observation.

    An episode of T steps has T + 1 rows (the final observation has a zero action); only
    ``sample_index`` rows carry an action. ``episode_end[i]`` is the last row of row i's episode,
    which is what HER needs to relabel goals with index arithmetic alone. ``segment_end[i]`` is
    the last row of row i's goal segment: in continuing episodes the expert heads for one goal
    until it reaches it, then for the next, so a relabelled goal beyond the segment may lie
    behind a detour; without goal switches it equals ``episode_end``.
    """

    observations: np.ndarray  # [N, obs_dim] float32, proprioceptive features
    positions: np.ndarray  # [N, goal_dim] float32, achieved goal (maze coordinates)
    actions: np.ndarray  # [N, action_dim] float32
    episode_end: np.ndarray  # [N] int64
    sample_index: np.ndarray  # [M] int64, rows with an action
    segment_end: np.ndarray  # [N] int64, last row of the row's goal segment (<= episode_end)
    # [N, goal_dim] float32, the position as the agent senses it in the arrays' variant
    # (:func:`~hispo_pl.tasks.agent_position`, set by :meth:`for_task`); None: ``positions``
    agent_positions: np.ndarray | None = None

    def content_digest(self) -> str:
        """SHA-256 (16 hex digits) of the arrays' contents. A dataset is regenerated on every
        new machine, and the physics library's version changes what the expert collects; two
        runs whose digests agree trained on the same episodes."""
        digest = hashlib.sha256()
        for array in (
            self.observations,
            self.positions,
            self.actions,
            self.episode_end,
            self.sample_index,
            self.segment_end,
        ):
            digest.update(str((array.dtype.str, array.shape)).encode())
            digest.update(np.ascontiguousarray(array).tobytes())
        return digest.hexdigest()[:16]

    @property
    def n_episodes(self) -> int:
        """Episodes with at least one sampled row (a split keeps its share of them)."""
        return int(len(np.unique(self.episode_end[self.sample_index])))

    def split_episodes(self, heldout: float, seed: int = 0) -> tuple[EpisodeArrays, EpisodeArrays]:
        """Split by episode into (train, held-out): ``round(heldout · episodes)`` episodes (at
        least one when ``heldout`` > 0 and there are two or more), drawn with ``seed``, are
        only ever scored on. The arrays are shared; each part samples only its own episodes'
        rows, and relabelled goals and subgoals never leave a row's episode, so nothing of a
        held-out episode reaches training. ``heldout=0`` returns the data twice (the paper's
        behaviour: decisions scored on the training data)."""
        if not 0.0 <= heldout < 1.0:
            raise ValueError(f"the held-out share must be in [0, 1), got {heldout}")
        ends = np.unique(self.episode_end[self.sample_index])
        n = round(heldout * len(ends))
        if heldout > 0 and len(ends) >= 2:
            n = min(max(n, 1), len(ends) - 1)
        if n == 0:
            return self, self
        chosen = np.random.default_rng(seed).choice(ends, size=n, replace=False)
        held = np.isin(self.episode_end[self.sample_index], chosen)
        return (
            replace(self, sample_index=self.sample_index[~held]),
            replace(self, sample_index=self.sample_index[held]),
        )

    def for_task(self, task: Task) -> EpisodeArrays:
        """The arrays as an agent in ``task``'s variant sees them."""
        observations = transform_observation(task, self.observations)
        return replace(
            self,
            observations=observations,
            actions=transform_action(task, self.actions),
            agent_positions=agent_position(task, observations, self.positions),
        )


def goal_segment_ends(desired_goal: np.ndarray) -> np.ndarray:
    """For each row of one episode, the (episode-local) row at which its goal was reached: the
    first row showing the next goal, or the last row. Rows of one goal form a segment."""
    n = len(desired_goal)
    changes = np.flatnonzero(np.any(desired_goal[1:] != desired_goal[:-1], axis=-1)) + 1
    bounds = np.append(changes, n - 1)  # inclusive end of each segment
    starts = np.concatenate([[0], changes])
    return np.repeat(bounds, np.diff(np.append(starts, n)))


class DatasetValuesError(UserError, ValueError):
    """A dataset holding NaN or infinite values, which would train and decide on garbage."""


def check_finite(dataset: str, episode: int, field: str, values: np.ndarray) -> None:
    """Refuse an episode's ``field`` unless every value is finite, naming where it is not."""
    bad = ~np.isfinite(values)
    if bad.any():
        step = int(np.argwhere(bad)[0][0])
        raise DatasetValuesError(
            f"the data of {dataset} is not usable: episode {episode} holds {int(bad.sum())} NaN "
            f"or infinite value(s) in {field} (first at step {step}). Regenerate the dataset "
            "(hispo-pl data generate NAME --overwrite) or drop the episode from it."
        )


OBSERVATION_KEYS = ("observation", "achieved_goal")  # desired_goal is read when present


def check_observation_keys(dataset: str, episode: int, observations) -> None:
    """Refuse an episode whose observations are not a dict with the keys training reads."""
    keys = sorted(observations) if isinstance(observations, dict) else None
    if keys is None or any(key not in observations for key in OBSERVATION_KEYS):
        held = f"the keys {', '.join(keys)}" if keys is not None else "no dict observations"
        raise DatasetValuesError(
            f"the data of {dataset} is not usable: episode {episode} has {held}; hispo-pl reads "
            "dict observations with 'observation' (the agent's features) and 'achieved_goal' "
            "(its position), and 'desired_goal' when present (goal changes mark segments), as "
            "the gymnasium-robotics mazes' observations are (docs/extending.md)"
        )


def episodes_to_arrays(episodes, dataset: str = "the dataset") -> EpisodeArrays:
    """Flatten Minari episodes (dict observations with ``observation`` and ``achieved_goal``;
    ``desired_goal``, when present, marks goal segments), refusing any that is not finite
    (:class:`DatasetValuesError`, naming ``dataset``, the episode and the field)."""
    obs, pos, act, end, idx, seg = [], [], [], [], [], []
    start = 0
    for k, ep in enumerate(episodes):
        check_observation_keys(dataset, getattr(ep, "id", k), ep.observations)
        o = np.asarray(ep.observations["observation"], dtype=np.float32)
        n = len(o)  # T + 1
        a = np.zeros((n, np.asarray(ep.actions).shape[-1]), dtype=np.float32)
        a[: n - 1] = ep.actions
        p = np.asarray(ep.observations["achieved_goal"], dtype=np.float32)
        goals = ep.observations.get("desired_goal")
        goals = None if goals is None else np.asarray(goals)
        # as training reads them (float32: a value too large for it is infinite there too)
        named = {"observation": o, "achieved_goal": p, "desired_goal": goals, "actions": a}
        for field, values in named.items():
            if values is not None:
                check_finite(dataset, getattr(ep, "id", k), field, values)
        obs.append(o)
        pos.append(p)
        act.append(a)
        end.append(np.full(n, start + n - 1, dtype=np.int64))
        idx.append(np.arange(start, start + n - 1, dtype=np.int64))
        seg.append(start + (goal_segment_ends(goals) if goals is not None else np.full(n, n - 1)))
        start += n
    if not obs:
        raise ValueError("dataset has no episodes")
    return EpisodeArrays(*(np.concatenate(x) for x in (obs, pos, act, end, idx, seg)))


def load_episodes(source: str | Task) -> EpisodeArrays:
    """Episodes of a task's maze (our local dataset) or of any Minari id.

    ``source`` is a task (spec), or a Minari id such as ``D4RL/pointmaze/umaze-v2`` which is
    downloaded when online. Variants are not applied here: see :meth:`EpisodeArrays.for_task`.
    """
    ds, episodes = open_dataset(source)
    return episodes_to_arrays(ds.iterate_episodes(episodes), ds.spec.dataset_id)


def physics_mismatch(requirements, installed) -> str | None:
    """Which physics packages a dataset was collected with (its Minari ``requirements``, pip
    pins such as ``mujoco==3.14.0``) differ from ``installed`` (package -> version), or None;
    a package a dataset did not pin is not compared.

    Example:
        >>> physics_mismatch(["mujoco==3.14.0", "gymnasium==1.4.0"], {"mujoco": "4.0.1"})
        'mujoco 3.14.0 (installed: 4.0.1)'
    """
    pins = dict(pin.split("==", 1) for pin in requirements or () if "==" in pin)
    diffs = [
        f"{package} {pins[package]} (installed: {installed.get(package)})"
        for package in packages.PHYSICS_PACKAGES
        if package in pins and pins[package] != installed.get(package)
    ]
    return ", ".join(diffs) or None


def collected_in_other_physics(ds) -> str | None:
    """:func:`physics_mismatch` of an opened Minari dataset against the installed packages."""
    requirements = ds.storage.metadata.get("requirements")
    installed = {p: packages.installed_version(p) for p in packages.PHYSICS_PACKAGES}
    return physics_mismatch(requirements, installed)


def open_dataset(source: str | Task):
    """The Minari dataset of ``source`` (see :func:`load_episodes`), downloaded if it is a
    missing Minari id, and the episode indices a task reads (``None``: all), without reading
    any episode: what a data module's ``prepare_data`` needs. Our local data are only read
    here; :func:`~hispo_pl.data.generation.generate_missing` makes them.

    Raises:
        DatasetNotFoundError: our local dataset is missing or too small (naming the command
            that makes it), or a Minari id is neither stored nor downloadable."""
    import minari

    source = dataset_source(source)
    if isinstance(source, Task):
        task = source
        dataset_id = local_dataset_id(task.dataset_name)
        if not dataset_exists(dataset_id):
            raise DatasetNotFoundError(
                f"dataset {dataset_id} not found under {dataset_path('')}; create it with\n"
                f"  hispo-pl data generate {task.dataset_name}"
            )
        ds = minari.load_dataset(dataset_id)
        if ds.total_episodes < task.episodes:
            raise DatasetNotFoundError(
                f"{task} asks for {task.episodes} episodes but {dataset_id} holds "
                f"{ds.total_episodes}; regenerate it with\n  hispo-pl data generate "
                f"{task.dataset_name} --episodes {task.episodes} --overwrite"
            )
        return ds, range(task.episodes)
    dataset_id = source
    if not dataset_exists(dataset_id):
        try:
            ds = minari.load_dataset(dataset_id, download=True)
        except ImportError as err:  # minari's remote support is an optional extra
            raise DatasetNotFoundError(
                f"Minari dataset {dataset_id} is not stored under {dataset_path('')}, and "
                f"downloading it needs the optional package {err.name or err} (pip install "
                f"'minari[hf]' or {err.name}).\nOr generate local expert data instead, e.g.\n"
                "  hispo-pl data generate pointmaze-umaze"
            ) from err
        except Exception as err:  # no network, unknown id, remote down
            raise DatasetNotFoundError(
                f"Minari dataset {dataset_id} is not stored under {dataset_path('')} and could not "
                f"be downloaded ({type(err).__name__}: {err}).\nOffline, generate local expert "
                "data instead, e.g.\n  hispo-pl data generate pointmaze-umaze\nand name the task "
                "(pointmaze-umaze-N[500]) rather than the remote id."
            ) from err
    else:
        ds = minari.load_dataset(dataset_id)
    return ds, None


def dataset_stats(dataset_id: str) -> dict:
    """Metadata of a stored dataset (episodes, steps, description, and the packages it was
    collected with: another MuJoCo collects other episodes)."""
    import minari

    ds = minari.load_dataset(dataset_id)
    return {
        "id": dataset_id,
        "episodes": ds.total_episodes,
        "steps": ds.total_steps,
        "description": ds.storage.metadata.get("description", ""),
        "collected_with": list(ds.storage.metadata.get("requirements") or []),
    }


def known_dataset_names() -> list[str]:
    return [f"{f}-{m}" for f, fam in FAMILIES.items() for m in fam.mazes]
