"""The environment families a task names (PointMaze, AntMaze, the game mazes): each one's
sizes, mazes with their defaults, the variants that make sense for its agent, what its policies
see by default and its expert, so that no code elsewhere tests a family's name; and the variants
themselves. :mod:`hispo_pl.tasks` parses task specs over them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

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
    # the PAC zero-shot criterion's tolerances when the method config leaves them unset: how
    # far (subgoal offset in maze units, action) the best existing point may predict the new
    # task's data, in this family's units; measured to separate the tasks HiSPO's pruning
    # kept a new anchor for from those it dropped it on (docs/studies/zero-shot.md)
    pac_eps: dict[str, float] = field(default_factory=lambda: {"high": 0.5, "low": 1.0})
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
        # no distance separates the game mazes' tasks as the pruning does (a pruned low
        # anchor's 90 % quantile lies among the kept ones'): tolerances below every measured
        # one, so the criterion does not fire and HiSPO-PAC trains as HiSPO
        pac_eps={"high": 0.5, "low": 0.1},
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
        # eight joint torques and cells four units wide: PointMaze's (1.0, 0.5) would take a
        # low anchor for permuted actions and refuse a high one for a repeated maze
        pac_eps={"high": 0.65, "low": 0.5},
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
