"""LightningDataModule for one task: its expert data (generated when missing), HER batches."""

from __future__ import annotations

from dataclasses import replace
from typing import Literal

import lightning as L
import torch
from torch.utils.data import DataLoader

from ..console import say
from ..errors import ConfigError
from ..task_families import HIGH_INPUTS, LOW_INPUTS
from ..tasks import Task, parse_stream, parse_task, unseen_variant_tasks, unseen_variants_message
from .batch_stream import _Batches
from .datasets import (
    DatasetUse,
    EpisodeArrays,
    collected_in_other_physics,
    dataset_id_of,
    dataset_source,
    load_episodes,
    open_dataset,
)
from .generation import generate_missing
from .sampler import DeviceHERSampler, HERConfig, HERSampler, Horizon, MixedSampler, Strategy

DEFAULT_TASK = "pointmaze-umaze-N[500]"
Split = Literal["train", "heldout"]
Sampling = Literal["host", "device"]


def _input_choice(flag: str, value: str, choices: dict) -> str:
    """``value`` of ``--data.<flag>`` if it is ``family`` or one of ``choices``."""
    if value != "family" and value not in choices:
        raise ValueError(
            f"--data.{flag} must be family or one of {', '.join(choices)}, got {value!r}"
        )
    return value


_WARNED_OF_PHYSICS: set[str] = set()


def warn_of_other_physics(ds, source: str | Task) -> None:
    """Say once per process when a dataset was collected on another MuJoCo than this run rolls
    out on: its episodes are not what generating it here would give, and the expert moved in
    other physics than the policies are evaluated in."""
    dataset_id = ds.spec.dataset_id
    mismatch = collected_in_other_physics(ds)
    if mismatch is None or dataset_id in _WARNED_OF_PHYSICS:
        return
    _WARNED_OF_PHYSICS.add(dataset_id)
    ours = dataset_source(source)
    remedy = (
        f"`hispo-pl data generate {ours.dataset_name} --overwrite` collects it on this one"
        if isinstance(ours, Task)
        else "collected on this one, its episodes would differ"
    )
    say(
        f"{dataset_id} was collected on {mismatch}: this run's rollouts move in other "
        f"physics than its expert did; {remedy} (docs/data.md, Reproducing a dataset)"
    )


class TaskDataModule(L.LightningDataModule):
    """Expert data of one task, relabelled by HER, as batches of ``batch_size``.

    Args:
        task: task spec, e.g. ``pointmaze-umaze-N[500]`` (variant applied to the data);
            default: the stream's first task, else ``pointmaze-umaze-N[500]``. From Python, a
            :class:`~hispo_pl.tasks.Task` too (as ``stream``'s entries), which is not parsed
            again.
        dataset: a Minari id to read instead of our local data for the task's maze, e.g.
            ``D4RL/pointmaze/umaze-v2`` (downloaded when online); a single-maze run only.
        datasets: a Minari id per maze of a stream, e.g.
            ``{"pointmaze-umaze": "D4RL/pointmaze/umaze-v2"}``; mazes not named use our local
            data.
        batch_size: samples per gradient step.
        waysteps: subgoal distance; default per maze from the paper.
        her_temperature: mean goal offset (steps); default per maze from the paper.
        her_strategy: exponential | uniform | geometric.
        goal_horizon: clip relabelled goals at the ``segment`` end (the point where the expert
            reached the goal it was heading for: past it, a continuing episode's path is a
            detour to the next goal, not a way to the relabelled one) or at the ``episode``
            end (the reference's).
        steps_per_epoch: batches per epoch (Trainer's ``max_steps`` bounds the total).
        seed: sampler seed.
        stream: a stream name (pointmaze-1, pointmaze-2, antmaze-1, antmaze-2, videogame-1,
            videogame-2, amazeville-1, amazeville-2, simpletown-1, simpletown-2) or a list of
            task specs: ``hispo-pl fit`` then trains the whole stream with the ContinualLoop
            (each task in turn; the module is built for the first one's sizes), and the
            evaluation at each task's end covers every task of the stream.
        replay: also train on every earlier task of the stream, each batch split in equal
            shares over the tasks seen so far (the RPL baseline: an upper bound that keeps old
            data, which the continual setting forbids). Task-end callbacks still draw their
            batches from the current task only.
        low_inputs: what the low policy of the model sees (linked to its ``low_obs`` and
            ``low_velocity``): ``observation`` (the subgoal's features and the observation),
            ``goal`` (the subgoal's features and the velocity of the sensed position),
            ``subgoal`` (the subgoal's features only), or ``family``: the family's own choice
            (PointMaze ``goal``; AntMaze and the game mazes ``observation``, whose agents need
            their body state or depth image).
        high_inputs: what the high policy (and the flat BC policy) sees besides the features of
            the goal offset, the sensed position and the goal (linked to the model's
            ``high_obs``): ``observation`` (the authors'), ``goal`` (the velocity of the sensed
            position instead), or ``family``: the family's choice (AntMaze ``goal``;
            PointMaze and the game mazes ``observation``). The position is sensed through the
            observation where the family's observation holds it (PointMaze:
            :func:`~hispo_pl.tasks.agent_position`), so an
            observation variant reaches goal-space inputs there; elsewhere it is in maze
            coordinates, and inputs under which no policy would see a stream's IO or PO task
            are refused.
        holdout: share of each task's episodes never trained on (chosen by episode, with a
            fixed seed): the subspace search, ``L_curr`` and the zero-shot test score on them,
            so that a decision measures how a policy generalises, not how well it memorised.
            0 trains on every episode and scores decisions on training data (the paper).
        transitions: batches also hold ``next_observation`` and ``next_position`` (the next
            row of the episode), for methods that learn a critic (CSP); off by default, so
            other methods' batches are unchanged.
        sampler: where training batches are drawn: ``host`` (numpy on the CPU, copied to the
            run's device each step: the committed runs' batches) or ``device`` (torch on the
            run's device, from a generator seeded with ``seed``: nothing is copied from the
            host per step; the same distributions, another random stream). Task-end callbacks'
            batches are drawn on the host either way.
        group: batches per Trainer step, served as one group of ``[group, B, ...]`` tensors
            that a captured step (``--model.init_args.optim.captured true``) trains on as
            ``group`` updates; 1: one batch per step. ``steps_per_epoch`` counts groups.
    """

    def __init__(
        self,
        task: str | None = None,
        dataset: str | None = None,
        datasets: dict[str, str] | None = None,
        batch_size: int = 1024,
        waysteps: int | None = None,
        her_temperature: float | None = None,
        her_strategy: Strategy = "exponential",
        goal_horizon: Horizon = "segment",
        steps_per_epoch: int = 1000,
        seed: int = 0,
        stream: str | list[str] | None = None,
        replay: bool = False,
        holdout: float = 0.1,
        transitions: bool = False,
        low_inputs: Literal["family", "observation", "goal", "subgoal"] = "family",
        high_inputs: Literal["family", "observation", "goal"] = "family",
        sampler: Sampling = "host",
        group: int = 1,
    ):
        super().__init__()
        if sampler not in ("host", "device"):
            raise ValueError(f"--data.sampler must be host or device, got {sampler!r}")
        if group < 1:
            raise ValueError(f"--data.group must be >= 1 (batches per Trainer step), got {group}")
        self.sampling, self.group = sampler, group
        if not 0.0 <= holdout < 1.0:
            raise ValueError(
                f"--data.holdout must be in [0, 1) (a share of episodes), got {holdout}"
            )
        self.tasks: list[Task] = [] if stream is None else parse_stream(stream)  # parsed once
        self.task: Task = (
            parse_task(task) if task is not None else (self.tasks or [parse_task(DEFAULT_TASK)])[0]
        )
        families = {t.env_family.name for t in self.tasks}
        if len(families) > 1:
            raise ValueError(
                f"a stream's tasks must share one environment family (one set of observation "
                f"and action sizes); got {', '.join(sorted(families))} in {self.stream}"
            )
        mazes = sorted({t.dataset_name for t in self.tasks or [self.task]})
        if dataset is not None and len(mazes) > 1:
            raise ConfigError(
                f"--data.dataset names one dataset, but the stream has {len(mazes)} mazes "
                f"({', '.join(mazes)}); name one per maze with --data.datasets, e.g. "
                f'\'{{"{mazes[0]}": "<minari id>", ...}}\''
            )
        unknown = sorted(set(datasets or {}) - set(mazes))
        if unknown:
            raise ConfigError(
                f"--data.datasets names {', '.join(unknown)}, not a maze of this run "
                f"({', '.join(mazes)})"
            )
        for name in [dataset, *(datasets or {}).values()]:
            if name is not None:
                dataset_source(name)  # a name that is neither a spec nor a Minari id: say so now
        self.dataset = dataset
        self.datasets = dict(datasets or {})
        self.batch_size = batch_size
        self._her_options = (waysteps, her_temperature, her_strategy, goal_horizon)
        self.her = self.her_config(self.task)
        self.steps_per_epoch = steps_per_epoch
        self.seed = seed
        self.replay = replay
        self.holdout = holdout
        self.low_inputs = _input_choice("low_inputs", low_inputs, LOW_INPUTS)
        self.high_inputs = _input_choice("high_inputs", high_inputs, HIGH_INPUTS)
        unseen = unseen_variant_tasks(self.tasks or [self.task], self.low_obs or self.high_obs)
        if unseen:
            raise ConfigError(unseen_variants_message(unseen, f"with {self.inputs_summary},"))
        self.transitions = transitions
        self.data: EpisodeArrays | None = None  # every episode of the task
        self.splits: dict[Split, EpisodeArrays] = {}  # "train" and "heldout" parts of data
        self.replayed: list[tuple[EpisodeArrays, HERConfig]] = []
        # the dataset the task reads and its episodes, once prepare_data has opened it
        self.dataset_use: DatasetUse | None = None

    def her_config(self, task: Task) -> HERConfig:
        """The relabelling of ``task``: the explicit options, else the paper's per-maze values."""
        waysteps, temperature, strategy, horizon = self._her_options
        return HERConfig(
            waysteps=waysteps if waysteps is not None else task.defaults.waysteps,
            temperature=temperature if temperature is not None else task.defaults.her_temperature,
            strategy=strategy,
            goal_horizon=horizon,
        )

    @property
    def stream(self) -> list[str] | None:
        """The stream's task specs (``None`` for a single task)."""
        return [t.spec for t in self.tasks] or None

    def earlier_tasks(self) -> list[Task]:
        """Distinct tasks of the stream before the current one (its first occurrence)."""
        if not self.tasks:
            return []
        if self.task not in self.tasks:
            raise ValueError(f"task {self.task.spec} is not in the stream {self.stream}")
        earlier = self.tasks[: self.tasks.index(self.task)]
        return [t for t in dict.fromkeys(earlier) if t != self.task]

    @property
    def obs_dim(self) -> int:
        return self.task.env_family.obs_dim

    @property
    def action_dim(self) -> int:
        return self.task.env_family.action_dim

    @property
    def goal_dim(self) -> int:
        return self.task.env_family.goal_dim

    @property
    def low_obs(self) -> bool:
        """Whether the low policy sees the observation (see ``low_inputs``)."""
        return self._low_inputs()[0]

    @property
    def low_velocity(self) -> bool:
        """Whether the low policy sees the goal-space velocity (see ``low_inputs``)."""
        return self._low_inputs()[1]

    @property
    def high_obs(self) -> bool:
        """Whether the high policy sees the observation (see ``high_inputs``)."""
        return HIGH_INPUTS[self.resolved_inputs[1]]

    def _low_inputs(self) -> tuple[bool, bool]:
        return LOW_INPUTS[self.resolved_inputs[0]]

    @property
    def resolved_inputs(self) -> tuple[str, str]:
        """(low, high) inputs with ``family`` replaced by the family's own choice."""
        family = self.task.env_family
        low = family.low_inputs if self.low_inputs == "family" else self.low_inputs
        high = family.high_inputs if self.high_inputs == "family" else self.high_inputs
        return low, high

    @property
    def inputs_summary(self) -> str:
        """``--data.low_inputs goal and --data.high_inputs goal``, ``family`` resolved."""
        (low, high), named = self.resolved_inputs, (self.low_inputs, self.high_inputs)
        parts = [
            f"--data.{flag} {value}" + (" (the family's)" if given == "family" else "")
            for flag, value, given in zip(
                ("low_inputs", "high_inputs"), (low, high), named, strict=True
            )
        ]
        return " and ".join(parts)

    @property
    def binary_actions(self) -> int:
        """Leading action entries that are buttons (the game mazes' gamepad)."""
        return self.task.env_family.binary_actions

    def dataset_for(self, task: Task) -> str | Task:
        """Where ``task``'s episodes come from: the Minari id named for its maze, else our
        local dataset of the maze (made on first use)."""
        return self.datasets.get(task.dataset_name) or self.dataset or task

    def prepare_data(self) -> None:
        """Make our local data of the task (and, with ``replay``, of the earlier ones) if they
        are missing, then open the task's dataset."""
        for task in [self.task, *(self.earlier_tasks() if self.replay else [])]:
            generate_missing(self.dataset_for(task))
        ds, episodes = open_dataset(self.dataset_for(self.task))
        count = ds.total_episodes if episodes is None else len(episodes)
        self.dataset_use = DatasetUse(ds.spec.dataset_id, count)
        warn_of_other_physics(ds, self.dataset_for(self.task))

    def describe(self) -> str:
        """The task as the console names it: its spec, or, when a Minari dataset is named for
        it, the maze and variant and that dataset (with its episode count once opened), since
        the spec's ``[episodes]`` then counts nothing."""
        source = self.dataset_for(self.task)
        if isinstance(dataset_source(source), Task):
            return self.task.spec
        task = self.task
        used = self.dataset_use if self.dataset_use is not None else dataset_id_of(source)
        return f"{task.family}-{task.maze}-{task.variant} from {used}"

    def setup(self, stage: str | None = None) -> None:
        if self.data is None:
            stored = load_episodes(self.dataset_for(self.task))
            if self.dataset_use is not None:
                self.dataset_use = replace(self.dataset_use, digest=stored.content_digest())
            self.data = stored.for_task(self.task)
            if self.holdout > 0 and self.data.n_episodes < 2:
                raise ConfigError(
                    f"{self.task} has {self.data.n_episodes} episode: --data.holdout "
                    f"{self.holdout} needs at least 2 (one to train on, one to score the "
                    "decisions on); give the task more episodes, or --data.holdout 0 to score "
                    "them on the training data"
                )
            self._check_sizes()
            train, heldout = self.data.split_episodes(self.holdout)
            self.splits = {"train": train, "heldout": heldout}
        if self.replay and not self.replayed:  # earlier tasks' training episodes only
            self.replayed = [
                (
                    load_episodes(self.dataset_for(task))
                    .for_task(task)
                    .split_episodes(self.holdout)[0],
                    self.her_config(task),
                )
                for task in self.earlier_tasks()
            ]

    def _check_sizes(self) -> None:
        """Refuse data whose observation, position or action sizes are not the family's: the
        model is built for the family's sizes and rollouts run in its environment."""
        family, data = self.task.env_family, self.data
        found = {
            "observation": (data.observations.shape[-1], family.obs_dim),
            "achieved_goal": (data.positions.shape[-1], family.goal_dim),
            "action": (data.actions.shape[-1], family.action_dim),
        }
        wrong = [f"{k} {have} (not {want})" for k, (have, want) in found.items() if have != want]
        if wrong:
            raise ConfigError(
                f"{dataset_id_of(self.dataset_for(self.task))} does not fit {self.task}: its "
                f"episodes hold {', '.join(wrong)} values per step; a {family.name} dataset needs "
                f"observation {family.obs_dim}, achieved_goal {family.goal_dim} and action "
                f"{family.action_dim}, collected in {self.task.gym_id} or an env like it"
            )

    def _sampler(
        self,
        data: EpisodeArrays,
        her: HERConfig,
        batch_size: int,
        seed: int,
        device: torch.device | None = None,
    ):
        """A host sampler, or one on ``device`` where given."""
        step = self.task.env_family.step_seconds
        if device is not None:
            return DeviceHERSampler(
                data, her, batch_size, seed, step, self.transitions, device=device
            )
        return HERSampler(
            data, her, batch_size, seed=seed, step_seconds=step, transitions=self.transitions
        )

    def _training_device(self) -> torch.device | None:
        """Where training batches are drawn: the run's device with ``sampler: device``."""
        if self.sampling != "device":
            return None
        trainer = self.trainer
        return trainer.strategy.root_device if trainer is not None else torch.device("cpu")

    def fixed_batches(
        self,
        n: int,
        seed: int,
        batch_size: int | None = None,
        device: torch.device | None = None,
        split: Split = "heldout",
    ) -> list[dict[str, torch.Tensor]]:
        """``n`` HER batches of the current task's ``split`` episodes from their own seeded
        sampler (independent of the training stream): what task-end callbacks score candidates
        on (``heldout``) or measure a Fisher on (``train``)."""
        data = self.splits[split]
        sampler = self._sampler(data, self.her, batch_size or self.batch_size, seed)
        return [{k: v.to(device) for k, v in sampler.sample().items()} for _ in range(n)]

    def train_dataloader(self) -> DataLoader:
        device = self._training_device()
        sampler = self._sampler(self.splits["train"], self.her, self.batch_size, self.seed, device)
        if self.replayed:
            earlier = [
                self._sampler(data, her, self.batch_size, self.seed + 1 + k, device)
                for k, (data, her) in enumerate(self.replayed)
            ]
            sampler = MixedSampler([sampler, *earlier], self.batch_size)
        batches = _Batches(sampler, self.steps_per_epoch, self.group)
        return DataLoader(batches, batch_size=None, num_workers=0)
