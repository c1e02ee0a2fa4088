"""Task specs and named streams, written the way the paper writes them.

A task spec is ``<family>-<maze>[-<variant>][[<episodes>]]``, e.g. ``pointmaze-umaze-PO[500]``:
PointMaze, U-maze, permuted observations, 500 expert episodes. Variant defaults to ``N``
and episodes to 500. A stream is a named list of task specs (``pointmaze-1``), or a random
one drawn over a family's tasks (``random-antmaze-8@3``: 8 AntMaze tasks, generator seed 3).
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from .errors import UserError

VARIANTS: dict[str, str] = {
    "N": "normal: no change",
    "IA": "inverted actions: every action entry negated",
    "IO": "inverted observations: every observation feature negated",
    "PA": "permuted actions: cyclic shift by one actuator group (one leg for the ant)",
    "PO": "permuted observations: cyclic shift of the observation features by one",
}


@dataclass(frozen=True)
class MazeDefaults:
    """Per-maze defaults: gymnasium-robotics name, rollout step limit, HER settings."""

    env_name: str
    max_episode_steps: int
    waysteps: int
    her_temperature: float


LowInputs = Literal["observation", "goal", "subgoal"]
LOW_INPUTS: dict[str, tuple[bool, bool]] = {  # name -> (low_obs, low_velocity) of the backbone
    "observation": (True, False),  # features(subgoal − pos) + the observation (variant applied)
    "goal": (False, True),  # features(subgoal − pos) + goal-space velocity: goal space only
    "subgoal": (False, False),  # features(subgoal − pos) only (the authors' low policy)
}
HighInputs = Literal["observation", "goal"]
HIGH_INPUTS: dict[str, bool] = {  # name -> high_obs of the backbone
    "observation": True,  # [features(goal − pos), observation, pos, goal] (the authors')
    "goal": False,  # [features(goal − pos), goal-space velocity, pos, goal]: goal space only
}
# variants that change only what the agent senses: a task of one of them is a new task only
# to a policy that reads the observation (positions, goals and success stay in maze coordinates)
OBSERVATION_VARIANTS: tuple[str, ...] = ("IO", "PO")


@dataclass(frozen=True)
class Family:
    """An environment family (PointMaze, AntMaze, the game mazes) and everything that differs
    between them, so that no code elsewhere tests a family's name."""

    name: str
    env_id: str  # format string over the maze's env_name
    obs_dim: int
    action_dim: int
    goal_dim: int
    action_group: int  # entries per actuator group: PA shifts the actions by this much
    mazes: dict[str, MazeDefaults]
    env_kwargs: dict = field(default_factory=dict)
    variants: tuple[str, ...] = tuple(VARIANTS)  # the variants that make sense for this agent
    default_episodes: int = 500  # dataset episodes per maze when a spec names none
    binary_actions: int = 0  # leading action entries that are buttons (Bernoulli in the policy)
    step_seconds: float = 0.01  # time between two observations: turns position steps into velocity
    low_inputs: LowInputs = "observation"  # what the low policy sees by default (LOW_INPUTS)
    high_inputs: HighInputs = "observation"  # what the high policy sees by default (HIGH_INPUTS)
    expert: str = ""  # "module:Class" of the data-collecting expert (imported when needed)
    expert_reads_weights: bool = False  # the expert's policy comes from a weights file
    # "module:Class" of its FamilyBehaviour (hispo_pl.envs.family): env registration and
    # collection, episodes, reset options, drawing (imported when needed)
    behaviour: str = ""
    game: bool = False  # a video-game maze: its Gymnasium id carries no variant
    # HiSPO's pruning tolerance per subspace when the method config leaves it unset: a low
    # anchor carries over at a higher loss on the continuous-control mazes
    # (docs/studies/pruning.md); the game mazes' own is in _game_family
    pruning_eps: dict[str, float] = field(default_factory=lambda: {"high": 0.1, "low": 0.6})
    # whether the observation holds the position (its first goal_dim features): the policies
    # then read the position where the observation holds it, so that an observation variant
    # moves it too; else the position is a channel apart, in maze coordinates in every variant
    position_in_observation: bool = False
    # how a new anchor starts when the method config leaves ``anchor_init`` unset: from the
    # mean of the others (a new task builds on the old ones), or ``random`` (the game mazes,
    # where starting from an earlier maze's anchors costs the new task, docs/studies/new-anchor.md)
    anchor_init: Literal["mean", "random"] = "mean"


def _game_family(
    name: str, title: str, mazes: tuple[str, ...], defaults: MazeDefaults, episodes: int
) -> Family:
    """A family of the paper's Godot mazes rebuilt on MuJoCo (:mod:`hispo_pl.envs.videogame`):
    the same agent and gamepad in every maze (6 buttons + a rotation target; observation 127
    values besides position and goal); mazes differ by topology only, so the gamepad has no
    variant but N. ``defaults`` holds the step limit and HER settings shared by its mazes."""
    return Family(
        name=name,
        env_id=f"hispo_pl/{title}_{{}}-v0",
        obs_dim=127,
        action_dim=8,
        goal_dim=3,
        action_group=1,
        mazes={m: replace(defaults, env_name=m) for m in mazes},
        variants=("N",),
        default_episodes=episodes,
        binary_actions=6,
        step_seconds=0.1,  # decisions at 10 Hz
        # a closed door or a raised block changes what to do in a few states only, so the mean
        # loss moves little where the behaviour changes a lot: prune only at nearly equal loss
        pruning_eps={"high": 0.05, "low": 0.05},
        anchor_init="random",
        expert="hispo_pl.envs.videogame.expert:GameExpert",
        behaviour="hispo_pl.envs.games:GameMazes",
        game=True,
    )


FAMILIES: dict[str, Family] = {
    "pointmaze": Family(
        name="pointmaze",
        # a point mass needs no more than its sensed position and velocity below; the high
        # policy reads the observation (docs/studies/inputs.md)
        low_inputs="goal",
        high_inputs="observation",
        position_in_observation=True,  # its observation is x, y, vx, vy
        expert="hispo_pl.envs.experts:PointMazeExpert",
        behaviour="hispo_pl.envs.robotics:RoboticsMazes",
        env_id="PointMaze_{}-v3",
        obs_dim=4,
        action_dim=2,
        goal_dim=2,
        action_group=1,
        mazes={
            "umaze": MazeDefaults("UMaze", 300, waysteps=50, her_temperature=100.0),
            "medium": MazeDefaults("Medium", 600, waysteps=25, her_temperature=75.0),
            "large": MazeDefaults("Large", 800, waysteps=25, her_temperature=100.0),
        },
    ),
    "antmaze": Family(
        name="antmaze",
        high_inputs="goal",  # where to go next depends on the maze, not on the legs' state
        env_id="AntMaze_{}-v5",
        obs_dim=27,
        action_dim=8,
        goal_dim=2,
        action_group=2,
        mazes={
            "umaze": MazeDefaults("UMaze", 700, waysteps=10, her_temperature=50.0),
            "medium": MazeDefaults("Medium", 1000, waysteps=15, her_temperature=50.0),
            "large": MazeDefaults("Large", 1000, waysteps=15, her_temperature=50.0),
        },
        env_kwargs={"include_cfrc_ext_in_observation": False},
        expert="hispo_pl.envs.experts:AntMazeExpert",
        behaviour="hispo_pl.envs.robotics:RoboticsMazes",
        expert_reads_weights=True,
        step_seconds=0.05,  # 5 MuJoCo steps of 0.01 s per action
    ),
    "amazeville": _game_family(
        "amazeville",
        "AmazeVille",
        ("HOOO", "HOOX", "HXOO", "HXOX", "LOOO", "LOOX", "LXOO", "LXOX"),
        MazeDefaults("", 300, waysteps=10, her_temperature=100.0),
        episodes=100,
    ),
    "simpletown": _game_family(
        "simpletown",
        "SimpleTown",
        ("BASE", "OOO", "OOX", "OXO", "XOO", "XXO", "XOX", "OXX"),
        MazeDefaults("", 100, waysteps=3, her_temperature=15.0),
        episodes=250,
    ),
}

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
