"""Task specs and named streams, written the way the paper writes them.

A task spec is ``<family>-<maze>[-<variant>][[<episodes>]]``, e.g. ``pointmaze-umaze-PO[500]``:
PointMaze, U-maze, permuted observations, 500 expert episodes. Variant defaults to ``N``
and episodes to 500. A stream is a named list of task specs (``pointmaze-1``), or a random
one drawn over a family's tasks (``random-antmaze-8@3``: 8 AntMaze tasks, generator seed 3).
The families and variants a spec names are :mod:`hispo_pl.task_families`'.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass

import numpy as np

from .errors import UserError
from .task_families import FAMILIES, OBSERVATION_VARIANTS, VARIANTS, Family, MazeDefaults

DEFAULT_EPISODES = 500

_SPEC_RE = re.compile(
    r"^(?P<family>[a-z]+)-(?P<maze>[a-z]+|[A-Z]+)(?:-(?P<variant>[A-Z]+))?(?:\[(?P<episodes>\d+)\])?$"
)

GRAMMAR = (
    "task spec grammar: <family>-<maze>[-<variant>][[<episodes>]]\n"
    f"  family   : {' | '.join(FAMILIES)}\n"
    "  maze     : umaze | medium | large (pointmaze, antmaze);\n"
    "             HOOO | HOOX | HXOO | HXOX | LOOO | LOOX | LXOO | LXOX (amazeville);\n"
    "             BASE | OOO | OOX | OXO | XOO | XXO | XOX | OXX (simpletown)\n"
    f"  variant  : {' | '.join(VARIANTS)} (default N; the game mazes only N)\n"
    "  episodes : positive integer (default 500; amazeville 100, simpletown 250)\n"
    "  examples : pointmaze-umaze, pointmaze-umaze-PO[500], antmaze-large-IA[100],\n"
    "             amazeville-HXOO[100], simpletown-OXO[250]"
)


class TaskSpecError(UserError, ValueError):
    """A task spec or stream name that does not parse; the message shows the grammar."""


@dataclass(frozen=True)
class Task:
    """One task of a stream: an environment family, a maze, a variant and a dataset size."""

    family: str
    maze: str
    variant: str = "N"
    episodes: int = DEFAULT_EPISODES

    @property
    def spec(self) -> str:
        return f"{self.family}-{self.maze}-{self.variant}[{self.episodes}]"

    @property
    def env_family(self) -> Family:
        return FAMILIES[self.family]

    @property
    def defaults(self) -> MazeDefaults:
        return FAMILIES[self.family].mazes[self.maze]

    @property
    def env_id(self) -> str:
        return self.env_family.env_id.format(self.defaults.env_name)

    @property
    def gym_id(self) -> str:
        """The Gymnasium id of the task as hispo-pl evaluates it (registered on ``import
        hispo_pl.envs``): ``hispo_pl/PointMaze_UMaze-PO-v3`` for a maze variant; the game mazes,
        which have only the normal variant, keep their own id."""
        if self.env_family.game:
            return self.env_id
        name, version = self.env_id.rsplit("-v", 1)
        return f"hispo_pl/{name}-{self.variant}-v{version}"

    @property
    def dataset_name(self) -> str:
        """Datasets are stored once per maze, in the normal variant."""
        return f"{self.family}-{self.maze}"

    def __str__(self) -> str:
        return self.spec


def reads_as_task_spec(text: str) -> bool:
    """Whether ``text`` has the shape of a task spec (``<family>-<maze>[-<variant>][[<n>]]``),
    valid or not: what tells a task spec from a Minari dataset id (whose name ends in
    ``-v<version>`` or follows a namespace, neither of which a spec can hold)."""
    return _SPEC_RE.match(text.strip()) is not None


def parse_task(spec: str | Task) -> Task:
    """Parse ``pointmaze-umaze-PO[500]`` into a :class:`Task`; malformed specs show the grammar."""
    if isinstance(spec, Task):
        return spec
    m = _SPEC_RE.match(spec.strip())
    if m is None:
        raise TaskSpecError(f"malformed task spec {spec!r}\n{GRAMMAR}")
    family, maze = m["family"], m["maze"]
    variant = m["variant"] or "N"
    if family not in FAMILIES:
        raise TaskSpecError(f"unknown family {family!r} in {spec!r}\n{GRAMMAR}")
    if maze not in FAMILIES[family].mazes:
        raise TaskSpecError(f"unknown maze {maze!r} in {spec!r}\n{GRAMMAR}")
    if variant not in VARIANTS:
        raise TaskSpecError(f"unknown variant {variant!r} in {spec!r}\n{GRAMMAR}")
    if variant not in FAMILIES[family].variants:
        raise TaskSpecError(
            f"the {family} family has no variant {variant!r} (only "
            f"{', '.join(FAMILIES[family].variants)}) in {spec!r}\n{GRAMMAR}"
        )
    episodes = int(m["episodes"]) if m["episodes"] else FAMILIES[family].default_episodes
    if episodes <= 0:
        raise TaskSpecError(f"episodes must be positive in {spec!r}\n{GRAMMAR}")
    return Task(family, maze, variant, episodes)


_STREAM_SHAPES: dict[str, list[tuple[str, str]]] = {
    "1": [("umaze", "N"), ("large", "N"), ("umaze", "PO"), ("medium", "IO")],
    "2": [("umaze", "PA"), ("medium", "PO"), ("medium", "N"), ("medium", "N")],
}

STREAMS: dict[str, list[str]] = {
    f"{family}-{k}": [f"{family}-{maze}-{variant}[{DEFAULT_EPISODES}]" for maze, variant in shape]
    for family in ("pointmaze", "antmaze")
    for k, shape in _STREAM_SHAPES.items()
}
# topological streams (paper appendix A.1.2): doors open or close, blocks rise or sink
STREAMS |= {
    "videogame-1": [f"amazeville-{m}[100]" for m in ("HOOO", "HXOO", "LOOO", "LOOX")],
    "videogame-2": [f"amazeville-{m}[100]" for m in ("LOOX", "HXOO", "HOOO", "LXOX")],
    "amazeville-1": [f"amazeville-{m}[100]" for m in ("HOOX", "HXOX", "HXOX", "HOOX")],
    "amazeville-2": [f"amazeville-{m}[100]" for m in ("LOOO", "LOOO", "LXOX", "LXOO")],
    "simpletown-1": [f"simpletown-{m}[250]" for m in ("BASE", "OXO", "BASE", "OOX")],
    "simpletown-2": [f"simpletown-{m}[250]" for m in ("BASE", "OXX", "XOO", "OXX")],
}


RANDOM_STREAM = re.compile(r"^random-(?P<family>[^@]+)-(?P<n>\d+)@(?P<seed>\d+)$")
RANDOM_GRAMMAR = (
    f"random-<family>-<n>@<seed> (family: {' | '.join(FAMILIES)}; n >= 1 tasks; "
    "seed >= 0), e.g. random-antmaze-8@3"
)


def task_spec(family: str, maze: str, variant: str = "N") -> str:
    """A task's spec as the named streams write it: the game mazes, whose only variant is N,
    without it; every spec at the family's default episodes."""
    fam = FAMILIES[family]
    name = f"{family}-{maze}" if fam.game else f"{family}-{maze}-{variant}"
    return f"{name}[{fam.default_episodes}]"


def task_space(family: str) -> list[str]:
    """Every task of ``family`` (maze × variant, in the order the family lists them): what a
    random stream draws from, in a fixed order so that every machine draws alike."""
    if family not in FAMILIES:
        raise TaskSpecError(f"unknown family {family!r}; known: {', '.join(FAMILIES)}")
    fam = FAMILIES[family]
    return [task_spec(family, maze, variant) for maze in fam.mazes for variant in fam.variants]


def _draw(family: str, seed: int, i: int) -> int:
    """Task ``i``'s draw: a hash, not a generator, so no library version changes it."""
    return int.from_bytes(hashlib.sha256(f"{family}/{seed}/{i}".encode()).digest(), "big")


def random_stream(family: str, n: int, seed: int) -> list[str]:
    """``n`` tasks drawn uniformly, with repeats, from :func:`task_space`; task ``i`` depends on
    the family, the seed and ``i`` only, so a longer stream of the same family and seed extends
    a shorter one. Adding a maze or a variant to a family changes its random streams."""
    space = task_space(family)
    return [space[_draw(family, seed, i) % len(space)] for i in range(n)]


def parse_random_stream(name: str) -> tuple[str, int, int] | None:
    """``random-antmaze-8@3`` → ``("antmaze", 8, 3)``; None for a name that is not random.

    Raises:
        TaskSpecError: a ``random-`` name that breaks the grammar (the message shows it).
    """
    if not name.startswith("random-"):
        return None
    m = RANDOM_STREAM.match(name)
    if m is None:
        raise TaskSpecError(f"malformed random stream {name!r}: write {RANDOM_GRAMMAR}")
    family, n, seed = m["family"], int(m["n"]), int(m["seed"])
    if family not in FAMILIES:
        raise TaskSpecError(f"unknown family {family!r} in {name!r}: write {RANDOM_GRAMMAR}")
    if n < 1:
        raise TaskSpecError(f"a random stream needs n >= 1 tasks in {name!r}: {RANDOM_GRAMMAR}")
    if name != f"random-{family}-{n}@{seed}":
        raise TaskSpecError(
            f"write {name!r} as random-{family}-{n}@{seed} (no leading zeros): one name per stream"
        )
    return family, n, seed


def stream_specs(name: str) -> list[str]:
    """The task specs of a stream name: a named stream (``pointmaze-1``) or a random one."""
    random = parse_random_stream(name)
    if random is not None:
        return random_stream(*random)
    if name not in STREAMS:
        raise TaskSpecError(
            f"unknown stream {name!r}; known streams: {', '.join(sorted(STREAMS))}; a random "
            f"stream: {RANDOM_GRAMMAR}; or give a list of task specs"
        )
    return list(STREAMS[name])


def parse_stream(stream: str | list[str]) -> list[Task]:
    """A stream name (``pointmaze-1``, ``random-antmaze-8@3``) or an explicit list of task
    specs, as tasks."""
    specs = stream_specs(stream) if isinstance(stream, str) else stream
    return [parse_task(s) for s in specs]


def unseen_variant_tasks(tasks: list[Task], reads_observation: bool) -> list[Task]:
    """The tasks whose variant changes only the observation (IO, PO) when no policy reads the
    observation and the family's position is a channel apart: each would look to every policy
    exactly like the same maze's N task."""
    if reads_observation:
        return []
    return list(
        dict.fromkeys(
            t
            for t in tasks
            if t.variant in OBSERVATION_VARIANTS and not t.env_family.position_in_observation
        )
    )


def agent_position(task: Task, observation, position):
    """The position as the agent senses it, given the observation in ``task``'s variant and
    the position in maze coordinates (last axis; numpy or torch): where the family's
    observation holds the position, its first ``goal_dim`` features, so an observation variant
    moves it; else ``position`` itself. Goals and the success test stay in maze coordinates."""
    family = task.env_family
    return observation[..., : family.goal_dim] if family.position_in_observation else position


def unseen_variants_message(tasks: list[Task], inputs: str) -> str:
    """One line: which tasks a configuration leaves unseen, why, and what to change."""
    specs = ", ".join(t.spec for t in tasks)
    return (
        f"{specs}: {inputs} no policy reads the observation, so an observation variant "
        "would look exactly like its N task; set --data.low_inputs observation or "
        "--data.high_inputs observation (or leave both at family)"
    )


# --- variants: the same pure transforms serve the env wrapper and the dataset -------------


def transform_observation(task: Task, obs: np.ndarray) -> np.ndarray:
    """The observation features the agent sees in ``task`` given the normal ones (last axis)."""
    if task.variant == "IO":
        return -obs
    if task.variant == "PO":
        return np.roll(obs, 1, axis=-1)
    return obs


def transform_action(task: Task, action: np.ndarray) -> np.ndarray:
    """The action an agent must output in ``task`` to produce the normal ``action``."""
    if task.variant == "IA":
        return -action
    if task.variant == "PA":
        return np.roll(action, task.env_family.action_group, axis=-1)
    return action


def untransform_action(task: Task, action: np.ndarray) -> np.ndarray:
    """Inverse of :func:`transform_action`: the normal action an agent's output produces."""
    if task.variant == "IA":
        return -action
    if task.variant == "PA":
        return np.roll(action, -task.env_family.action_group, axis=-1)
    return action
