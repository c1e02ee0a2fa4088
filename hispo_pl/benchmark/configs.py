"""Settings a benchmark needs before any run starts (the step budget, the datasets), read
from the same YAML files and overrides the runs will get."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path


def _override_value(overrides: Sequence[str], key: str) -> str | None:
    """The last value given to ``--key`` in a jsonargparse argument list (``--k v`` or
    ``--k=v``), or None."""
    value = None
    for i, arg in enumerate(overrides):
        if arg == key and i + 1 < len(overrides):
            value = overrides[i + 1]
        elif arg.startswith(key + "="):
            value = arg.split("=", 1)[1]
    return value


_UNSET = object()


def configured_value(configs: Sequence[Path], overrides: Sequence[str], key: str):
    """The value ``fit`` will see for a dotted ``key`` (``trainer.max_steps``): the last
    ``--key`` in ``overrides`` (parsed as YAML, as jsonargparse does), else the last config
    file (in order) that sets it, else None."""
    import yaml  # a dependency of jsonargparse and lightning

    given = _override_value(overrides, f"--{key}")
    if given is not None:
        return yaml.safe_load(given)
    value = None
    for path in configs:
        node = yaml.safe_load(Path(path).read_text()) or {}
        for part in key.split("."):
            node = node.get(part, _UNSET) if isinstance(node, dict) else _UNSET
        if node is not _UNSET:
            value = node
    return value


def saved_setting(config_file: Path, key: str):
    """The value a finished run's saved ``config.yaml`` holds for ``key``: a dotted key, or a
    method knob (``eps_low``), which the run wrote into the callbacks that take it (the first
    of them that sets it); None when unset."""
    import yaml

    from ..methods import all_knobs, config_callbacks

    knob = all_knobs().get(key)
    if knob is None:
        return configured_value([config_file], [], key)
    config = yaml.safe_load(Path(config_file).read_text()) or {}
    for cls, callback in config_callbacks(config):
        for target, param in knob.targets.items():
            value = (callback.get("init_args") or {}).get(param)
            if cls is not None and issubclass(cls, target) and value is not None:
                return value
    return None


def configured_max_steps(configs: Sequence[Path], overrides: Sequence[str] = ()) -> int | None:
    """Gradient steps per task that ``fit`` will use (``trainer.max_steps``)."""
    steps = configured_value(configs, overrides, "trainer.max_steps")
    return None if steps is None else int(steps)


def datasets_needed(configs: Sequence[Path], overrides: Sequence[str] = ()) -> dict[str, int]:
    """Our local maze datasets a run reads (``pointmaze-umaze`` → episodes it needs); empty
    when ``data.dataset`` names another Minari dataset or no stream is configured."""
    from ..tasks import parse_stream

    stream = configured_value(configs, overrides, "data.stream")
    if not stream or configured_value(configs, overrides, "data.dataset"):
        return {}
    needed: dict[str, int] = {}
    for task in parse_stream(stream):
        needed[task.dataset_name] = max(needed.get(task.dataset_name, 0), task.episodes)
    return needed


def runs_datasets(runs: Sequence) -> dict[str, int]:
    """:func:`datasets_needed` of every planned run (``configs`` and ``argv`` each), merged:
    each local dataset with the most episodes any run reads of it."""
    needed: dict[str, int] = {}
    for run in runs:
        for name, episodes in datasets_needed(run.configs, run.argv).items():
            needed[name] = max(needed.get(name, 0), episodes)
    return needed


def prepare_datasets(needed: dict[str, int]) -> None:
    """Generate the missing local datasets here, once, before the runs start: runs that each
    generated a missing dataset on first use would race on the same files."""
    from ..data.datasets import dataset_exists, default_episodes, local_dataset_id
    from ..data.generation import generate_dataset

    for name, episodes in sorted(needed.items()):
        if not dataset_exists(local_dataset_id(name)):
            print(f"[benchmark] generating the {name} expert dataset before the runs start")
            generate_dataset(name, episodes=max(episodes, default_episodes(name)))


def episodes_here(stream: str | list[str]) -> dict[tuple[str, int], str]:
    """The digest of the episodes each task of ``stream`` reads from our local datasets, as
    its run will record it (``datasets[i]`` of ``results.json``), for the datasets made here."""
    from ..data.datasets import dataset_exists, load_episodes, local_dataset_id
    from ..tasks import parse_stream

    here: dict[tuple[str, int], str] = {}
    for task in parse_stream(stream):
        key = (local_dataset_id(task.dataset_name), task.episodes)
        if key not in here and dataset_exists(key[0]):
            here[key] = load_episodes(task).content_digest()
    return here
