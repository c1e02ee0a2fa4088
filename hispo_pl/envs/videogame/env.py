"""A 3-D navigation game on MuJoCo: the paper's Godot mazes driven with a gamepad.

The agent is a capsule (0.4 m radius, 1.8 m tall) with three slide joints and a yaw hinge, so
it moves in the plane, turns, and falls under gravity; contacts are frictionless, so it slides
along walls instead of sticking. Velocity actuators track the speed the buttons ask for
(walk 4 m/s, run 6 m/s); a jump sets a 5.4 m/s upward speed when standing (rises 1.5 m:
clears a 1 m block, not a 3 m wall). The env decides at 10 Hz (10 physics steps of 10 ms).

Observation (gymnasium-robotics dict, so the rest of hispo-pl needs nothing new):
``achieved_goal`` = position (3), ``desired_goal`` = goal (3), ``observation`` = orientation
(3) + velocity (3) + an 11 × 11 depth image (121) = 127 values; with position and goal that
is the paper's 133 inputs. Orientation is the heading as a unit vector (cos, sin, 0) rather
than an angle, which would jump at ±π. Floor / wall / goal contact, the timestep and the up
direction are in ``info``.

Action (8, like the authors' gamepad): buttons right, left, forward, backward, run, jump
(pressed when > 0.5; moves are relative to the heading) and a rotation target (cos, sin)
that the heading turns toward at up to 360°/s.
"""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np

from .layouts import Layout, layout

DT = 0.01  # physics step (s)
FRAME_SKIP = 10  # 10 Hz decisions
RADIUS, HALF_LENGTH = 0.4, 0.5  # capsule: 1.8 m tall
STAND_Z = RADIUS + HALF_LENGTH  # centre height standing on the floor
EYE_HEIGHT = 0.5  # above the centre
WALK_SPEED, RUN_SPEED = 4.0, 6.0
JUMP_SPEED = 5.4  # v^2 / 2g = 1.49 m
TURN_RATE = 2 * np.pi  # rad/s
MASS = 70.0
GOAL_RADIUS = 1.0  # success: the agent's centre within 1 m of the goal point
DEPTH_SIZE = 11
DEPTH_RANGE = 20.0  # metres; the depth image is distance / range, 1 = nothing within range
DEPTH_FOV = (np.deg2rad(120.0), np.deg2rad(60.0))  # horizontal, vertical
OBS_DIM = 3 + 3 + DEPTH_SIZE * DEPTH_SIZE
ACTION_DIM = 8
BUTTONS = ("right", "left", "forward", "backward", "run", "jump")
OBSTACLE_GROUPS = (0, 1, 2)  # floor, walls, blocks: what the depth rays see
_DECOR_GROUP = 3


def _boxes(layout: Layout) -> list[tuple[str, float, float, float, float, float]]:
    """Obstacles as boxes (kind, x, y, half-width, half-depth, height): one box per run of
    equal cells in a row, so a maze has tens of geoms rather than hundreds."""
    boxes = []
    heights = layout.heights()
    grid = layout.array()
    rows, cols = grid.shape
    for r in range(rows):
        c = 0
        while c < cols:
            ch = grid[r, c]
            end = c
            while end + 1 < cols and grid[r, end + 1] == ch:
                end += 1
            if ch != ".":
                x0, y1 = c * layout.cell, (rows - r) * layout.cell
                x1, y0 = (end + 1) * layout.cell, (rows - r - 1) * layout.cell
                kind = "wall" if ch == "#" else "block"
                boxes.append(
                    (
                        kind,
                        (x0 + x1) / 2,
                        (y0 + y1) / 2,
                        (x1 - x0) / 2,
                        (y1 - y0) / 2,
                        heights[r, c],
                    )
                )
            c = end + 1
    return boxes


def maze_xml(layout: Layout) -> str:
    """The MJCF of a maze: floor, perimeter walls, the layout's walls (3 m, grey) and blocks
    (green), the agent and a goal marker (not collidable, invisible to the depth rays)."""
    width, depth = layout.size
    geoms = [
        f'<geom name="floor" type="plane" size="{width / 2 + 2} {depth / 2 + 2} 0.1" '
        f'pos="{width / 2} {depth / 2} 0" group="0" rgba="0.8 0.8 0.75 1"/>'
    ]
    t = 0.5  # perimeter wall half-thickness
    for i, (x, y, hx, hy) in enumerate(
        (
            (width / 2, -t, width / 2 + 2 * t, t),
            (width / 2, depth + t, width / 2 + 2 * t, t),
            (-t, depth / 2, t, depth / 2),
            (width + t, depth / 2, t, depth / 2),
        )
    ):
        geoms.append(
            f'<geom name="border{i}" type="box" size="{hx} {hy} 2" pos="{x} {y} 2" group="1" '
            'rgba="0.4 0.4 0.45 1"/>'
        )
    for i, (kind, x, y, hx, hy, h) in enumerate(_boxes(layout)):
        group, rgba = (1, "0.5 0.5 0.55 1") if kind == "wall" else (2, "0.3 0.7 0.3 1")
        geoms.append(
            f'<geom name="{kind}{i}" type="box" size="{hx} {hy} {h / 2}" pos="{x} {y} {h / 2}" '
            f'group="{group}" rgba="{rgba}"/>'
        )
    return f"""<mujoco model="{layout.name}">
  <compiler angle="radian"/>
  <option timestep="{DT}" gravity="0 0 -9.81"/>
  <default><geom condim="1" friction="0 0 0" solref="0.005 1"/></default>
  <visual><global offwidth="64" offheight="64"/></visual>
  <worldbody>
    <light pos="{width / 2} {depth / 2} 40" dir="0 0 -1" directional="true"/>
    {chr(10).join("    " + g for g in geoms).strip()}
    <body name="goal" mocap="true" pos="0 0 {STAND_Z}">
      <geom name="goal" type="sphere" size="0.5" contype="0" conaffinity="0" group="{_DECOR_GROUP}"
            rgba="1 0.2 0.2 0.8"/>
    </body>
    <body name="agent" pos="0 0 0">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <joint name="z" type="slide" axis="0 0 1"/>
      <joint name="yaw" type="hinge" axis="0 0 1"/>
      <geom name="agent" type="capsule" size="{RADIUS} {HALF_LENGTH}" mass="{MASS}"
            rgba="0.2 0.4 0.9 1"/>
      <geom name="nose" type="box" size="0.15 0.1 0.1" pos="{RADIUS} 0 {EYE_HEIGHT}"
            contype="0" conaffinity="0" mass="0.1" group="{_DECOR_GROUP}" rgba="1 1 0 1"/>
      <camera name="eye" pos="0 0 {EYE_HEIGHT}" xyaxes="0 -1 0 0 0 1" fovy="60"/>
    </body>
  </worldbody>
  <actuator>
    <velocity name="vx" joint="x" kv="{MASS * 25}" ctrlrange="-10 10"/>
    <velocity name="vy" joint="y" kv="{MASS * 25}" ctrlrange="-10 10"/>
  </actuator>
</mujoco>"""


def ray_directions(yaw: float) -> np.ndarray:
    """Unit vectors of the 11 × 11 depth rays for heading ``yaw``, row-major from the top-left
    of the view (row = elevation from +30° down to −30°, column = azimuth from left to right)."""
    az = yaw + np.linspace(DEPTH_FOV[0] / 2, -DEPTH_FOV[0] / 2, DEPTH_SIZE)
    el = np.linspace(DEPTH_FOV[1] / 2, -DEPTH_FOV[1] / 2, DEPTH_SIZE)
    az, el = np.meshgrid(az, el)
    return np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1
    ).reshape(-1, 3)


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    return (a + np.pi) % (2 * np.pi) - np.pi


def move_velocity(buttons: np.ndarray, yaw: float) -> np.ndarray:
    """World-frame (vx, vy) the pressed buttons ask for: moves relative to the heading,
    diagonal presses normalised, opposite presses cancel; run raises the speed."""
    right, left, forward, backward, run = (buttons[:5] > 0.5).astype(np.float64)
    local = np.array([forward - backward, left - right])  # x ahead, y to the left
    norm = np.linalg.norm(local)
    if norm == 0:
        return np.zeros(2)
    speed = RUN_SPEED if run else WALK_SPEED
    local = local / norm * speed
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([c * local[0] - s * local[1], s * local[0] + c * local[1]])


class GameNavEnv(gym.Env):
    """One video-game maze (AmazeVille or SimpleTown) as a goal-conditioned gymnasium env.

    ``reset(options={"start": (x, y), "goal": (x, y)})`` places the agent and the goal;
    without options they are drawn from the layout's start / goal points. The agent starts
    facing up the map (+y). ``continuing_task=True`` keeps the episode going after success
    (the step limit ends it); the default ends it on success, as evaluation needs.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        game: str = "amazeville",
        maze: str = "HOOO",
        continuing_task: bool = False,
        render_mode: str | None = None,
    ):
        self.layout = layout(game, maze)
        self.game, self.maze = game, maze
        self.continuing_task = continuing_task
        self.render_mode = render_mode
        self.model = mujoco.MjModel.from_xml_string(maze_xml(self.layout))
        self.data = mujoco.MjData(self.model)
        self._agent_body = self.model.body("agent").id
        self._agent_geom = self.model.geom("agent").id
        self._floor_geom = self.model.geom("floor").id
        self._goal_mocap = self.model.body("goal").mocapid[0]
        self._geomgroup = np.array(
            [1 if g in OBSTACLE_GROUPS else 0 for g in range(6)], dtype=np.uint8
        )
        self._ray_geom = np.zeros(DEPTH_SIZE * DEPTH_SIZE, dtype=np.int32)
        self._ray_dist = np.zeros(DEPTH_SIZE * DEPTH_SIZE, dtype=np.float64)
        self._renderer = None
        width, depth = self.layout.size
        hi = max(width, depth) + 10
        box = gym.spaces.Box
        self.observation_space = gym.spaces.Dict(
            {
                "observation": box(-np.inf, np.inf, (OBS_DIM,), np.float64),
                "achieved_goal": box(-hi, hi, (3,), np.float64),
                "desired_goal": box(-hi, hi, (3,), np.float64),
            }
        )
        self.action_space = box(
            low=np.array([0.0] * 6 + [-1.0, -1.0]), high=np.ones(ACTION_DIM), dtype=np.float64
        )
        self.goal = np.zeros(3)
        self.timestep = 0

    # --- state ------------------------------------------------------------------------
    @property
    def position(self) -> np.ndarray:
        return self.data.qpos[:3].copy()

    @property
    def yaw(self) -> float:
        return float(self.data.qpos[3])

    def _contacts(self) -> tuple[bool, bool]:
        """(standing on something, touching a wall or block side)."""
        floor = wall = False
        for i in range(self.data.ncon):
            con = self.data.contact[i]
            if self._agent_geom not in (con.geom1, con.geom2):
                continue
            if abs(con.frame[2]) > 0.7:  # contact normal mostly vertical
                floor = True
            else:
                wall = True
        return floor, wall

    def depth_image(self) -> np.ndarray:
        """Distances along the 11 × 11 rays from the agent's eye, over the range (1 = none)."""
        eye = self.position + np.array([0.0, 0.0, EYE_HEIGHT])
        vec = ray_directions(self.yaw)
        mujoco.mj_multiRay(
            self.model, self.data, eye, vec.reshape(-1), self._geomgroup, 1,
            self._agent_body, self._ray_geom, self._ray_dist, None, len(vec), DEPTH_RANGE,
        )  # fmt: skip
        dist = np.where(self._ray_geom < 0, DEPTH_RANGE, self._ray_dist)
        return np.clip(dist / DEPTH_RANGE, 0.0, 1.0)

    def _obs(self) -> dict:
        heading = np.array([np.cos(self.yaw), np.sin(self.yaw), 0.0])
        velocity = self.data.qvel[:3].copy()
        return {
            "observation": np.concatenate([heading, velocity, self.depth_image()]),
            "achieved_goal": self.position,
            "desired_goal": self.goal.copy(),
        }

    def _info(self) -> dict:
        floor, wall = self._contacts()
        reached = bool(np.linalg.norm(self.position - self.goal) <= GOAL_RADIUS)
        return {
            "success": reached,
            "floor_contact": floor,
            "wall_contact": wall,
            "goal_contact": reached,
            "timestep": self.timestep,
            "up": np.array([0.0, 0.0, 1.0]),
        }

    # --- gymnasium API -----------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        start, goal = self.layout.sample_start_goal(self.np_random)
        start = np.asarray(options.get("start", start), dtype=np.float64)
        goal = np.asarray(options.get("goal", goal), dtype=np.float64)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:4] = [start[0], start[1], STAND_Z, np.pi / 2]
        self.goal = np.array([goal[0], goal[1], STAND_Z])
        self.data.mocap_pos[self._goal_mocap] = self.goal
        self.timestep = 0
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), self._info()

    def step(self, action):
        action = np.clip(np.asarray(action, dtype=np.float64), self.action_space.low,
                         self.action_space.high)  # fmt: skip
        buttons, rot = action[:6], action[6:]
        if np.linalg.norm(rot) > 1e-3:
            turn = wrap_angle(np.arctan2(rot[1], rot[0]) - self.yaw)
            max_turn = TURN_RATE * DT * FRAME_SKIP
            self.data.qpos[3] = wrap_angle(self.yaw + np.clip(turn, -max_turn, max_turn))
        self.data.ctrl[:2] = move_velocity(buttons, self.yaw)
        if buttons[5] > 0.5 and self._contacts()[0] and self.data.qvel[2] <= 0.5:
            self.data.qvel[2] = JUMP_SPEED
        mujoco.mj_step(self.model, self.data, nstep=FRAME_SKIP)
        self.timestep += 1
        obs, info = self._obs(), self._info()
        reward = float(info["success"])
        terminated = info["success"] and not self.continuing_task
        return obs, reward, terminated, False, info

    def render(self):
        """A 64 × 64 RGB view from the agent's eye (needs a GL backend: MUJOCO_GL=egl or
        osmesa)."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, 64, 64)
        self._renderer.update_scene(self.data, camera="eye")
        return self._renderer.render()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
