"""Expert datasets as real Minari datasets: generated locally by our experts, or D4RL ids.

Datasets are stored once per maze, in the normal variant; a task's variant is applied to the
arrays at load time by the same pure transforms the env wrapper uses.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from ..errors import UserError
from .tasks import (
    FAMILIES,
    GAME_FAMILIES,
    Task,
    parse_task,
    transform_action,
    transform_observation,
)

NAMESPACE = "hispo"
DATASET_VERSION = 0
DEFAULT_SEED = 0


def default_episodes(name: str | Task) -> int:
    """Episodes a maze's dataset holds unless asked otherwise: 500 for PointMaze / AntMaze,
    the paper's 100 (AmazeVille) and 250 (SimpleTown) for the game mazes."""
    return parse_task(name).env_family.default_episodes


class DatasetNotFoundError(UserError, FileNotFoundError):
    """A dataset that is neither stored locally nor downloadable; says how to make one."""


def local_dataset_id(name: str) -> str:
    """Minari id of our local dataset for a maze: ``hispo/pointmaze-umaze-expert-v0``."""
    return f"{NAMESPACE}/{name}-expert-v{DATASET_VERSION}"


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
        return replace(
            self,
            observations=transform_observation(task, self.observations),
            actions=transform_action(task, self.actions),
        )


def goal_segment_ends(desired_goal: np.ndarray) -> np.ndarray:
    """For each row of one episode, the (episode-local) row at which its goal was reached: the
    first row showing the next goal, or the last row. Rows of one goal form a segment."""
    n = len(desired_goal)
    changes = np.flatnonzero(np.any(desired_goal[1:] != desired_goal[:-1], axis=-1)) + 1
    bounds = np.append(changes, n - 1)  # inclusive end of each segment
    starts = np.concatenate([[0], changes])
    return np.repeat(bounds, np.diff(np.append(starts, n)))


def episodes_to_arrays(episodes) -> EpisodeArrays:
    """Flatten Minari episodes (dict observations with ``observation`` and ``achieved_goal``;
    ``desired_goal``, when present, marks goal segments)."""
    obs, pos, act, end, idx, seg = [], [], [], [], [], []
    start = 0
    for ep in episodes:
        o = np.asarray(ep.observations["observation"], dtype=np.float32)
        n = len(o)  # T + 1
        a = np.zeros((n, np.asarray(ep.actions).shape[-1]), dtype=np.float32)
        a[: n - 1] = ep.actions
        obs.append(o)
        pos.append(np.asarray(ep.observations["achieved_goal"], dtype=np.float32))
        act.append(a)
        end.append(np.full(n, start + n - 1, dtype=np.int64))
        idx.append(np.arange(start, start + n - 1, dtype=np.int64))
        goals = ep.observations.get("desired_goal")
        seg.append(
            start
            + (goal_segment_ends(np.asarray(goals)) if goals is not None else np.full(n, n - 1))
        )
        start += n
    if not obs:
        raise ValueError("dataset has no episodes")
    return EpisodeArrays(*(np.concatenate(x) for x in (obs, pos, act, end, idx, seg)))


def load_episodes(source: str | Task, *, generate_if_missing: bool = True) -> EpisodeArrays:
    """Episodes of a task's maze (our local dataset, generated on first use) or of any Minari id.

    ``source`` is a task (spec), or a Minari id such as ``D4RL/pointmaze/umaze-v2`` which is
    downloaded when online. Variants are not applied here: see :meth:`EpisodeArrays.for_task`.
    """
    import minari

    if isinstance(source, Task) or "/" not in source:
        task = parse_task(source)
        dataset_id = local_dataset_id(task.dataset_name)
        if not dataset_exists(dataset_id):
            if not generate_if_missing:
                raise DatasetNotFoundError(
                    f"dataset {dataset_id} not found under {dataset_path('')}; create it with\n"
                    f"  hispo-pl data generate {task.dataset_name}"
                )
            generate_dataset(task.dataset_name, episodes=max(task.episodes, default_episodes(task)))
        ds = minari.load_dataset(dataset_id)
        if ds.total_episodes < task.episodes:
            raise DatasetNotFoundError(
                f"{task} asks for {task.episodes} episodes but {dataset_id} holds "
                f"{ds.total_episodes}; regenerate it with\n  hispo-pl data generate "
                f"{task.dataset_name} --episodes {task.episodes} --overwrite"
            )
        return episodes_to_arrays(ds.iterate_episodes(range(task.episodes)))
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
    return episodes_to_arrays(ds.iterate_episodes())


# --- generation --------------------------------------------------------------------------


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


def collect_episode(env, expert, rng: np.random.Generator, seed: int, noise: float, steps: int):
    """One continuing episode of ``steps`` steps from a random start cell; new goal cells are
    drawn by the env whenever the current one is reached. An episode in which the agent flips
    over (:func:`~hispo_pl.envs.agent_flipped`, the check evaluation uses) is cut at that step:
    its clean prefix is kept and ``flipped`` is set. Returns a dict of arrays."""
    from ..envs import agent_flipped
    from ..envs.mazes import free_cells, maze_array

    cells = free_cells(maze_array(env))
    i, j = rng.choice(len(cells), size=2, replace=False)
    obs, _ = env.reset(seed=seed, options={"reset_cell": cells[i], "goal_cell": cells[j]})
    expert.reset()
    keys = ("observation", "achieved_goal", "desired_goal")
    record = {k: [obs[k]] for k in keys}
    actions, rewards, success = [], [], []
    low, high = env.action_space.low, env.action_space.high
    flipped = False
    for _ in range(steps):
        action = expert.act(obs)
        action = np.clip(action + noise * rng.standard_normal(action.shape), low, high)
        goal_before = obs["desired_goal"]
        obs, reward, _, _, info = env.step(action)
        if agent_flipped(env):  # the transition into the flip is not kept
            flipped = True
            break
        reached = bool(np.linalg.norm(obs["achieved_goal"] - goal_before) <= 0.45)
        for k in keys:
            record[k].append(obs[k])
        actions.append(action)
        rewards.append(reward)
        success.append(reached)
    return _episode_arrays(record, actions, rewards, success, flipped)


def _episode_arrays(record: dict, actions, rewards, reached, flipped: bool) -> dict:
    """One collected episode as the arrays staged to disk (observation keys, actions, rewards,
    per-step goal reached, whether it was cut at a flip)."""
    out = {k: np.asarray(v) for k, v in record.items()}
    out["actions"] = np.asarray(actions, dtype=np.float32)
    out["rewards"] = np.asarray(rewards, dtype=np.float64)
    out["reached"] = np.asarray(reached, dtype=bool)
    out["flipped"] = np.asarray(flipped)
    return out


def collect_game_episode(env, expert, rng: np.random.Generator, seed: int, steps: int):
    """One video-game episode from a drawn start point to a drawn goal point, ending when the
    goal is touched (the env terminates) or after ``steps`` steps. Same dict of arrays as
    :func:`collect_episode`; ``reached`` marks the step that touched the goal."""
    start, goal = env.unwrapped.layout.sample_start_goal(rng)
    obs, _ = env.reset(seed=seed, options={"start": start, "goal": goal})
    expert.reset(rng)
    keys = ("observation", "achieved_goal", "desired_goal")
    record = {k: [obs[k]] for k in keys}
    actions, rewards, success = [], [], []
    for _ in range(steps):
        action = expert.act(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        for k in keys:
            record[k].append(obs[k])
        actions.append(action)
        rewards.append(reward)
        success.append(bool(info["success"]))
        if terminated or truncated:
            break
    return _episode_arrays(record, actions, rewards, success, flipped=False)


def expert_class(name: str | Task) -> type:
    """The expert class of a maze's family (its class attributes hold the collection noise)."""
    family = parse_task(name).family
    if family == "pointmaze":
        from ..envs.experts import PointMazeExpert

        return PointMazeExpert
    if family == "antmaze":
        from ..envs.experts import AntMazeExpert

        return AntMazeExpert
    if family in GAME_FAMILIES:
        from ..envs.videogame.expert import GameExpert

        return GameExpert
    raise NotImplementedError(f"no expert for the {family!r} family")


def make_expert(name: str, env, expert_weights: str | None = None):
    """The expert of a dataset family (``expert_weights``: the ant policy's file)."""
    cls = expert_class(name)
    if parse_task(name).family == "antmaze":
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
    from importlib.metadata import PackageNotFoundError, version

    pins = []
    for package in ("hispo-pl", "gymnasium", "gymnasium-robotics", "mujoco"):
        try:
            pins.append(f"{package}=={version(package)}")
        except PackageNotFoundError:
            pins.append(package)
    return pins


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
    complete; an incomplete one found in place (:func:`dataset_problem`) is rebuilt.
    """
    import minari
    from minari.data_collector import EpisodeBuffer

    from ..envs import make_env

    task = parse_task(name)
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
    if problem is None:
        minari.delete_dataset(dataset_id)
    elif problem != "missing":  # cut short by a kill while it was written: rebuild it
        shutil.rmtree(final)
    steps = task.defaults.max_episode_steps
    game = task.family in GAME_FAMILIES
    env = make_env(name) if game else make_env(name, continuing_task=True, reset_target=True)
    expert = make_expert(name, env, expert_weights)
    staging = dataset_path("") / ".staging" / f"{name}-seed{seed}-noise{noise}"
    staging.mkdir(parents=True, exist_ok=True)
    ok = failed = flips = kept_steps = 0
    for k in tqdm(range(episodes), desc=f"collecting {name}", disable=not progress, unit="ep"):
        path = staging / f"ep_{k:05d}.npz"
        if not path.exists():
            rng = np.random.default_rng([seed, k])
            ep_seed = seed * 1_000_003 + k
            ep = (
                collect_game_episode(env, expert, rng, ep_seed, steps)
                if game
                else collect_episode(env, expert, rng, ep_seed, noise, steps)
            )
            tmp = path.with_suffix(".tmp.npz")
            np.savez(tmp, **ep)
            tmp.replace(path)
    buffers = []
    for k in range(episodes):
        ep = dict(np.load(staging / f"ep_{k:05d}.npz"))
        r_ok, r_failed = _goal_stats(ep["desired_goal"][:-1], ep["reached"], steps)
        ok, failed = ok + r_ok, failed + r_failed
        flips += int(ep.get("flipped", False))
        n = len(ep["actions"])
        kept_steps += n
        ended = bool(game and ep["reached"][-1])  # a game episode ends by touching its goal
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
    cut = (
        f" {flips} of {episodes} episodes ended early because the agent flipped over: the "
        f"clean prefix is kept, {kept_steps} of {episodes * steps} steps."
        if flips
        else ""
    )
    if game:
        description = (
            f"{episodes} episodes on {task.env_id}, each from a start point to a goal point of "
            f"the layout, ending when the goal is touched or after {steps} steps; seed {seed}. "
            f"Planner-generated, not human play (the paper's data was played by people): the "
            f"expert '{expert.name}' ({expert.description}). Expert success: {ok}/{ok + failed}"
            f" = {success:.4f}. Stats: {json.dumps(stats)}"
        )
    else:
        description = (
            f"{episodes} continuing episodes of {steps} steps on {task.env_id}, collected by the "
            f"expert '{expert.name}' ({expert.description}) with Gaussian action noise std "
            f"{noise:g}, seed {seed}; a new goal cell is drawn each time the goal is reached. "
            f"Expert goal success: {ok}/{ok + failed} = {success:.4f} (a goal fails if not "
            f"reached within {steps} steps).{cut} Stats: {json.dumps(stats)}"
        )
    build = dataset_path("") / ".staging" / f"build-{name}"  # a killed build is redone
    shutil.rmtree(build, ignore_errors=True)
    with _minari_root(build):  # the dataset is written here, then moved into place whole
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
        (build / dataset_id / GENERATION_FILE).write_text(json.dumps(settings))
    final.parent.mkdir(parents=True, exist_ok=True)
    namespace_meta = build / NAMESPACE / "namespace_metadata.json"
    if namespace_meta.exists() and not (final.parent / namespace_meta.name).exists():
        shutil.copy(namespace_meta, final.parent / namespace_meta.name)
    if final.exists():  # an incomplete copy left by an older version
        shutil.rmtree(final)
    os.replace(build / dataset_id, final)
    shutil.rmtree(build, ignore_errors=True)
    shutil.rmtree(staging, ignore_errors=True)
    return dataset_id


def dataset_stats(dataset_id: str) -> dict:
    """Metadata of a stored dataset (episodes, steps, description)."""
    import minari

    ds = minari.load_dataset(dataset_id)
    return {
        "id": dataset_id,
        "episodes": ds.total_episodes,
        "steps": ds.total_steps,
        "description": ds.storage.metadata.get("description", ""),
    }


def known_dataset_names() -> list[str]:
    return [f"{f}-{m}" for f, fam in FAMILIES.items() for m in fam.mazes]
