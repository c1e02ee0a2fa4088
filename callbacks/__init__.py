"""The method's callbacks, as the repository lays them out: the code is the package
``hispo_pl.callbacks`` (``hispo_pl/callbacks/``), which this folder re-exports for a checkout
on ``PYTHONPATH``. Configurations and imports name ``hispo_pl.callbacks``: a top-level
``callbacks`` module would collide with other packages of that name, so the wheel ships only
the package."""

from hispo_pl.callbacks import *  # noqa: F403
from hispo_pl.callbacks import __all__  # noqa: F401
