"""The installed packages a run's numbers depend on, by name and version: what ``run.json``
records, what a dataset pins when it is made, and what a fit compares a dataset's pins with."""

from __future__ import annotations

# what moves a run's numbers: torch's arithmetic, and the physics the datasets are collected and
# the policies rolled out in (another MuJoCo, other episodes)
RESULT_PACKAGES = (
    "torch",
    "lightning",
    "numpy",
    "mujoco",
    "gymnasium",
    "gymnasium-robotics",
    "minari",
)
# what changes the expert's episodes and a rollout's successes outright
PHYSICS_PACKAGES = ("mujoco", "gymnasium-robotics")
# the pins a generated dataset records (Minari's ``requirements``)
DATASET_PACKAGES = ("hispo-pl", "gymnasium", "gymnasium-robotics", "mujoco", "numpy")


def installed_version(package: str) -> str | None:
    """``package``'s installed version, or None when it is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:
        return None
