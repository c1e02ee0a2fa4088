"""Video-game navigation mazes (AmazeVille, SimpleTown) rebuilt on MuJoCo."""

from .env import GameNavEnv, maze_xml
from .layouts import AMAZEVILLE_NAMES, SIMPLETOWN_NAMES, Layout, LayoutNameError, layout

__all__ = [
    "AMAZEVILLE_NAMES",
    "SIMPLETOWN_NAMES",
    "GameNavEnv",
    "Layout",
    "LayoutNameError",
    "layout",
    "maze_xml",
]
