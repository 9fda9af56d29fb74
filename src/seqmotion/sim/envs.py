"""Gymnasium environments of the two robot scenes, for other controllers and learners.

Importing this module registers

* ``seqmotion/PancakeArm-v0`` — keep a pancake on the spatula (:class:`PancakeArmEnv`);
* ``seqmotion/SlidingArm-v0`` — slide an object on a frying pan to a goal (:class:`SlidingArmEnv`).

(``gymnasium.make("seqmotion.sim.envs:seqmotion/PancakeArm-v0")`` imports it for you.)

An action is a tool command that the arm's task-space PD + DOB controller (1 ms, the
experiment's gains) tracks for ``frame_skip`` control periods — a chunk, as a seq2seq decoder
emits them. With ``action="pose"`` it is the 6-D pose ``[x, y, z, a, b, c]`` (attitude
convention of :mod:`seqmotion.sim.kinematics`); with ``action="planar"`` it is the task's own
coordinates: ``[y, z, θ]`` of the spatula (eq. 4.9) or ``[x_p, y_p]`` of the pan (eq. 3.28).
Within a chunk the command moves linearly (slerp for attitude) from the previous command to
the new one, with that constant velocity fed forward.

Observation (22 floats): tool position (3) and quaternion (4), tool linear and angular velocity
(6, world frame), the object's position (3) and velocity (3) relative to the tool in the tool
frame (x = the surface's down normal, z = along the tool), and the object's up axis in the tool
frame (3).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .arm import Arm, Place, get_scene, place_on_tool, weight
from .backend import CONTROL_DT, import_mujoco
from .control import TaskSpaceController, resolve_gains
from .kinematics import attitude_matrix, matrix_to_quat, quat_to_matrix
from .pancake import GAP_LIMIT, SLIP_LIMIT
from .render import Renderer
from .scene import (
    BLADE_HALF,
    OBJECT_HALF_HEIGHT,
    OBJECT_MASS,
    PAN_ORIGIN,
    PAN_RADIUS,
    PANCAKE_MASS,
    PANCAKE_ORIGIN,
    TOOL_PITCH,
)

OBS_DIM = 22


def _slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    dot = float(np.dot(q0, q1))
    if dot < 0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    return (np.sin((1 - s) * theta) * q0 + np.sin(s * theta) * q1) / np.sin(theta)


def _angular_velocity(q0: np.ndarray, q1: np.ndarray, duration: float) -> np.ndarray:
    """World-frame ω that turns attitude q0 into q1 in ``duration`` [rad/s]."""
    rel = quat_to_matrix(q1) @ quat_to_matrix(q0).T
    angle = np.arccos(np.clip((np.trace(rel) - 1) / 2, -1.0, 1.0))
    if angle < 1e-12:
        return np.zeros(3)
    axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]]) / (2 * np.sin(angle))
    return axis * angle / duration


class _ArmEnv(gym.Env):
    """Shared machinery: the arm, its controller, chunked commands, the observation."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}
    kind = ""

    def __init__(self, *, gains: str, frame_skip: int, action: str, render_mode: str | None,
                 camera: str, width: int, height: int) -> None:
        if frame_skip < 1:
            raise ValueError(f"frame_skip must be at least 1, got {frame_skip}")
        if action not in ("pose", "planar"):
            raise ValueError(f"action must be 'pose' or 'planar', got {action!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self._mj = import_mujoco()
        self.scene = get_scene(self.kind)
        self.gains = resolve_gains(gains)
        self.frame_skip = frame_skip
        self.action_mode = action
        self.render_mode = render_mode
        self._camera, self._size = camera, (width, height)
        self._renderer: Renderer | None = None
        self.arm = Arm(self.scene, self.gains)
        self.data = self.arm.data  # the arm's MjData, stepped in place
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float64)
        self._pos = np.zeros(3)
        self._quat = np.array([1.0, 0.0, 0.0, 0.0])

    # -- subclasses define these -------------------------------------------------------------
    def _start_pose(self, options: dict) -> np.ndarray:  # (6,) pose
        raise NotImplementedError

    def _place(self, options: dict) -> Place:
        raise NotImplementedError

    def _load(self) -> np.ndarray:
        raise NotImplementedError

    def _reward(self) -> tuple[float, bool, dict]:
        raise NotImplementedError

    def _planar_to_pose(self, a: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    # -- gymnasium API -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        options = dict(options or {})
        pose = np.asarray(self._start_pose(options), dtype=np.float64)
        self._pos = pose[:3].copy()
        self._quat = matrix_to_quat(attitude_matrix(pose[3:]))
        self.arm.reset(self._pos, self._quat, self._place(options), self._load())
        self._placed = self._relative()[0].copy()
        self._step_hold(20)  # let the object settle into contact (20 ms)
        return self._observation(), {}

    @property
    def controller(self) -> TaskSpaceController | None:
        """The arm's task-space controller (``None`` before the first :meth:`reset`)."""
        return self.arm.controller

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self.controller is None:
            raise RuntimeError("call reset() before step()")
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be finite with shape {self.action_space.shape}, got {a}")
        pose = self._planar_to_pose(a) if self.action_mode == "planar" else a
        pos1, quat1 = pose[:3], matrix_to_quat(attitude_matrix(pose[3:]))
        duration = self.frame_skip * CONTROL_DT
        twist = np.concatenate([(pos1 - self._pos) / duration, _angular_velocity(self._quat, quat1, duration)])
        still = np.zeros(6)
        for i in range(1, self.frame_skip + 1):
            s = i / self.frame_skip
            self.arm.step(self._pos + s * (pos1 - self._pos), _slerp(self._quat, quat1, s), twist, still)
        self._pos, self._quat = pos1.copy(), quat1
        unstable = self.arm.diverged() or not np.all(np.isfinite(self.data.qpos))
        reward, terminated, info = self._reward()
        if unstable:
            terminated, info["unstable"] = True, True
        return self._observation(), float(reward), bool(terminated), False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = Renderer(self.scene.model, *self._size)
        return self._renderer.render(self.data, self._camera)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- helpers -------------------------------------------------------------------------------
    def _step_hold(self, steps: int) -> None:
        """Hold the current command for ``steps`` control periods."""
        still = np.zeros(6)
        for _ in range(steps):
            self.arm.step(self._pos, self._quat, still, still)

    def _relative(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Object position, velocity and up axis in the tool frame."""
        mj, m, d, sc = self._mj, self.scene.model, self.data, self.scene
        mj.mj_kinematics(m, d)
        mj.mj_comPos(m, d)
        rot = d.site_xmat[sc.site].reshape(3, 3)
        pos = rot.T @ (d.qpos[sc.body_qpos : sc.body_qpos + 3] - d.site_xpos[sc.site])
        jac = np.zeros((3, m.nv))
        mj.mj_jac(m, d, jac, None, d.qpos[sc.body_qpos : sc.body_qpos + 3], m.site_bodyid[sc.site])
        vel = rot.T @ (d.qvel[sc.body_dof : sc.body_dof + 3] - jac @ d.qvel)
        up = rot.T @ quat_to_matrix(d.qpos[sc.body_qpos + 3 : sc.body_qpos + 7])[:, 2]
        return pos, vel, up

    def _observation(self) -> np.ndarray:
        d, sc = self.data, self.scene
        twist = self.controller.tool_twist(d)
        pos, vel, up = self._relative()
        return np.concatenate([d.site_xpos[sc.site], d.site_xquat[sc.site], twist, pos, vel, up]).astype(np.float64)


class PancakeArmEnv(_ArmEnv):
    """Keep the pancake on the spatula (chs. 2, 4 scene).

    Reward 1 per step while the pancake keeps contact (slip < 5 mm from where it was placed and
    gap < 2 mm: :data:`~seqmotion.sim.pancake.SLIP_LIMIT`, :data:`~seqmotion.sim.pancake.GAP_LIMIT`),
    else 0; the episode terminates once the pancake is off the blade. ``reset(options=...)``
    accepts ``start=(y, z, θ)``; the pancake is placed within ±``jitter`` m of the blade centre.
    """

    kind = "pancake"

    def __init__(self, *, gains: str = "ch2", frame_skip: int = 10, action: str = "planar",
                 jitter: float = 0.005, render_mode: str | None = None, camera: str = "oblique",
                 width: int = 480, height: int = 360) -> None:
        super().__init__(gains=gains, frame_skip=frame_skip, action=action, render_mode=render_mode,
                         camera=camera, width=width, height=height)
        self.jitter = float(jitter)
        if action == "planar":
            low, high = np.array([-0.35, -0.35, -2 * np.pi]), np.array([0.35, 0.35, 2 * np.pi])
        else:
            low = np.concatenate([PANCAKE_ORIGIN - 0.35, [-2 * np.pi, 0.0, -np.pi]])
            high = np.concatenate([PANCAKE_ORIGIN + 0.35, [2 * np.pi, np.pi, np.pi]])
        self.action_space = spaces.Box(low, high, dtype=np.float64)

    def _planar_to_pose(self, a: np.ndarray) -> np.ndarray:
        return np.array([PANCAKE_ORIGIN[0], PANCAKE_ORIGIN[1] + a[0], PANCAKE_ORIGIN[2] + a[1], a[2], TOOL_PITCH, 0.0])

    def _start_pose(self, options: dict) -> np.ndarray:
        y, z, theta = options.get("start", (0.0, 0.0, 0.0))
        return self._planar_to_pose(np.array([y, z, theta], dtype=np.float64))

    def _place(self, options: dict):
        offset = self.np_random.uniform(-self.jitter, self.jitter, size=2)
        return place_on_tool(self.scene, 0.0, offset)

    def _load(self) -> np.ndarray:
        return weight(PANCAKE_MASS)

    def _reward(self) -> tuple[float, bool, dict]:
        pos, _, _ = self._relative()
        slip = float(np.linalg.norm(pos[1:] - self._placed[1:]))
        gap = float(max(0.0, -pos[0]))
        in_contact = slip < SLIP_LIMIT and gap < GAP_LIMIT
        off = gap > 0.03 or abs(pos[1]) > BLADE_HALF[1] or abs(pos[2]) > BLADE_HALF[2]
        return (1.0 if in_contact else 0.0), off, {"slip": slip, "gap": gap, "in_contact": in_contact}


class SlidingArmEnv(_ArmEnv):
    """Slide the object on the frying pan to a goal in the pan frame (ch. 3 scene).

    Reward ``-|p_object - goal|`` [m] per step (pan frame, planar); the episode terminates if
    the object leaves the pan. ``reset(options=...)`` accepts ``goal=(x, y)``; otherwise the
    goal is drawn uniformly within ``goal_radius`` of the pan centre. The object starts at rest
    at the centre.
    """

    kind = "sliding"

    def __init__(self, *, gains: str = "ch3", frame_skip: int = 10, action: str = "planar",
                 goal_radius: float = 0.06, render_mode: str | None = None, camera: str = "front",
                 width: int = 480, height: int = 360) -> None:
        super().__init__(gains=gains, frame_skip=frame_skip, action=action, render_mode=render_mode,
                         camera=camera, width=width, height=height)
        self.goal_radius = float(goal_radius)
        self.goal = np.zeros(2)
        if action == "planar":
            low, high = np.array([-0.2, -0.2]), np.array([0.2, 0.2])
        else:
            low = np.concatenate([PAN_ORIGIN - 0.2, [-np.pi, 0.0, -np.pi]])
            high = np.concatenate([PAN_ORIGIN + 0.2, [np.pi, np.pi, np.pi]])
        self.action_space = spaces.Box(low, high, dtype=np.float64)

    def _planar_to_pose(self, a: np.ndarray) -> np.ndarray:
        return np.array([PAN_ORIGIN[0] + a[0], PAN_ORIGIN[1] + a[1], PAN_ORIGIN[2], 0.0, TOOL_PITCH, 0.0])

    def _start_pose(self, options: dict) -> np.ndarray:
        return self._planar_to_pose(np.zeros(2))

    def _place(self, options: dict):
        if "goal" in options:
            self.goal = np.asarray(options["goal"], dtype=np.float64).reshape(2)
        else:
            r = self.goal_radius * np.sqrt(self.np_random.uniform())
            phi = self.np_random.uniform(-np.pi, np.pi)
            self.goal = np.array([r * np.cos(phi), r * np.sin(phi)])
        return place_on_tool(self.scene, OBJECT_HALF_HEIGHT, np.zeros(2))

    def _load(self) -> np.ndarray:
        return weight(OBJECT_MASS)

    def _reward(self) -> tuple[float, bool, dict]:
        pos, _, _ = self._relative()
        planar = pos[[2, 1]]
        height = -pos[0] - OBJECT_HALF_HEIGHT
        off = bool(np.linalg.norm(planar) > PAN_RADIUS + 0.01 or height < -0.01)
        dist = float(np.linalg.norm(planar - self.goal))
        return -dist, off, {"distance": dist, "object": planar, "goal": self.goal.copy()}


def _register() -> None:
    registered = gym.envs.registry
    for env_id, entry in (("seqmotion/PancakeArm-v0", "seqmotion.sim.envs:PancakeArmEnv"),
                          ("seqmotion/SlidingArm-v0", "seqmotion.sim.envs:SlidingArmEnv")):
        if env_id not in registered:
            gym.register(id=env_id, entry_point=entry, max_episode_steps=300)


_register()

__all__: list[Any] = ["PancakeArmEnv", "SlidingArmEnv", "OBS_DIM"]
