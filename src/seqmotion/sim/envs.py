"""Gymnasium environments of the two robot scenes, for other controllers, learners and closed loops.

``import seqmotion`` registers them (:mod:`seqmotion.sim.registration`):

* ``seqmotion/PancakeArm-v0`` — keep a pancake on the spatula (:class:`PancakeArmEnv`);
* ``seqmotion/SlidingArm-v0`` — slide an object on a frying pan to a goal (:class:`SlidingArmEnv`).

>>> import gymnasium as gym
>>> import seqmotion
>>> env = gym.make("seqmotion/PancakeArm-v0", action="accel", frame_skip=1)   # 1 kHz, the decoder's output

**Time.** One :meth:`~_ArmEnv.step` runs ``frame_skip`` control periods (1 ms each) of the arm's
task-space PD + disturbance-observer controller with the experiment's gains. ``env.dt`` is the
time of one step, ``frame_skip × 1 ms`` (default 10 ms), and ``metadata["render_fps"] = 1 / dt``
(default 100): one rendered frame per step, so a video written at that rate (e.g. by
``gymnasium.wrappers.RecordVideo``) plays in real time. An episode is truncated after
``time_limit`` seconds of simulated time (default 3 s, whatever the ``frame_skip``).

**Actions** (physical units; ``env.action_layout`` names the components). The mode is the ``action=``
keyword (``gym.make("seqmotion/PancakeArm-v0", action="accel")``); an unknown keyword is refused by name. With
``normalize_actions=True`` the action space is ``Box(-1, 1)``, mapped linearly onto the bounds
below (``env.to_physical(a)``, ``env.to_action(physical)`` convert). Actions are not clipped.

==========  ===============================================  ======================================
``action``  PancakeArm (spatula, eq. 4.9)                    SlidingArm (pan, eq. 3.28)
==========  ===============================================  ======================================
"planar"    ``[y, z, θ]`` to reach at the end of the step    ``[x_p, y_p]``, ±0.2 m
(default)   [m, m, rad], ±0.35 m, ±0.35 m, ±2π
"accel"     ``[a_y, a_z, a_θ]`` held over the step [m/s²,     ``[a_x, a_y]`` of the pan [m/s²],
            m/s², rad/s²], ±40, ±40, ±500: the Deformer's    ±20: the sliding planner's output
            output (its ``accel_layout``)                    (its ``accel_layout``)
"pose"      6-D tool pose ``[x, y, z, a, b, c]`` (attitude   the same, ±0.2 m around the pan's
            convention of :mod:`~seqmotion.sim.kinematics`)   origin
            [m, rad], ±0.35 m around the spatula's origin
==========  ===============================================  ======================================

``y, z`` are the tool site relative to :data:`~seqmotion.sim.scene.PANCAKE_ORIGIN`, ``x_p, y_p``
relative to :data:`~seqmotion.sim.scene.PAN_ORIGIN`. With ``"planar"`` and ``"pose"`` the
command moves linearly (slerp for attitude) from the previous command to the target over the
step, with that constant velocity fed forward. With ``"accel"`` the environment integrates a
reference from rest at the start pose exactly as the models' double integrator does
(``p += v dt + ½ a dt²``, ``v += a dt`` per 1 ms period) and feeds its pose, velocity and
acceleration forward every period — what :func:`~seqmotion.sim.run_pancake` does with a
trajectory — so a decoder's accelerations can be applied one per step with ``frame_skip=1``;
``env.reference`` is that reference in the model's state layout.

A command whose pose the arm cannot reach (:func:`~seqmotion.sim.arm.workspace_problem`) is not
executed: the episode ends (``terminated``, ``info["out_of_workspace"]`` says why), as it does
when the simulation becomes unstable (``info["unstable"]``). After either, before the first
:meth:`~_ArmEnv.reset` and after a ``reset`` that raised, ``step`` raises :class:`ResetNeeded`.

**Observation** (float64). ``env.fields`` maps each name below to a :class:`Field` (its slice,
component names and units); ``env.observation_layout`` names all floats; ``env.model_state(obs)``
is the slice a model's generator reads (``env.model_layout`` its layout).

==========  ============  ============================================================================
slice       field         contents
==========  ============  ============================================================================
0:3         tool_pos      tool control site ``x, y, z`` [m], world frame
3:7         tool_quat     its attitude ``w, x, y, z``, world frame
7:10        tool_vel      its linear velocity [m/s], world frame
10:13       tool_omega    its angular velocity [rad/s], world frame
13:16       object_pos    object centre relative to the site [m], tool frame
16:19       object_vel    object velocity relative to the tool [m/s], tool frame
19:22       object_up     the object's up axis, tool frame (``[-1, 0, 0]`` lying flat, face up)
22:28       spatula       PancakeArm: ``y, z, θ, v_y, v_z, v_θ`` [m, m, rad, m/s, m/s, rad/s], the
                          pancake Deformer's state (θ the spatula's roll, unwrapped: continuous
                          over the episode); ``model_state`` = this
22:26       pan           SlidingArm: ``pan_x, pan_y, pan_v_x, pan_v_y`` [m, m/s]
26:30       object        SlidingArm: ``x, y, v_x, v_y`` [m, m/s], the object relative to the pan
                          centre, pan frame; ``model_state`` = ``pan`` + ``object``, the sliding
                          planner's state
==========  ============  ============================================================================

The tool frame: x is the surface's down normal, z points along the tool, y completes it (the
pan frame's x, y are the tool's z, y). World velocities are measured (``J(q) q̇``), noise-free.
"""

from __future__ import annotations

import difflib
import inspect
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..physics.integrator import integrate_numpy
from ..physics.layout import StateLayout
from ..tasks.pancake.physics import ACCEL_LAYOUT as PANCAKE_ACCEL
from ..tasks.pancake.physics import STATE_LAYOUT as PANCAKE_STATE
from ..tasks.sliding.physics import ACCEL_LAYOUT as PAN_ACCEL
from ..tasks.sliding.physics import PLAN_LAYOUT as SLIDING_STATE
from .arm import Arm, Place, get_scene, place_on_tool, weight, workspace_problem
from .backend import CONTROL_DT, import_mujoco
from .control import JointSpaceController, TaskSpaceController, resolve_gains
from .kinematics import Reference, attitude_matrix, matrix_to_quat, planar_tilt, quat_to_matrix
from .pancake import GAP_LIMIT, SLIP_LIMIT
from .render import Renderer
from .robot_models import Robot, resolve_robot
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

ACTIONS = ("planar", "accel", "pose")
"""The action modes (see the module docstring)."""
TIME_LIMIT = 3.0
"""Default episode length [s] of simulated time."""


class ResetNeeded(gym.error.ResetNeeded, RuntimeError):
    """:meth:`~_ArmEnv.step` was called before a successful :meth:`~_ArmEnv.reset`."""


@dataclass(frozen=True)
class Field:
    """A named group of observation floats: ``obs[..., field.slice]``."""

    slice: slice
    names: tuple[str, ...]
    units: tuple[str, ...]
    doc: str


def _fields(groups: list[tuple[str, tuple[str, ...], tuple[str, ...], str]]) -> dict[str, Field]:
    fields, start = {}, 0
    for name, names, units, doc in groups:
        fields[name] = Field(slice(start, start + len(names)), names, units, doc)
        start += len(names)
    return fields


_XYZ = ("x", "y", "z")
COMMON_FIELDS = [
    ("tool_pos", _XYZ, ("m",) * 3, "tool control site, world frame"),
    ("tool_quat", ("w", "x", "y", "z"), ("1",) * 4, "tool attitude, world frame"),
    ("tool_vel", _XYZ, ("m/s",) * 3, "tool linear velocity, world frame"),
    ("tool_omega", _XYZ, ("rad/s",) * 3, "tool angular velocity, world frame"),
    ("object_pos", _XYZ, ("m",) * 3, "object centre relative to the site, tool frame"),
    ("object_vel", _XYZ, ("m/s",) * 3, "object velocity relative to the tool, tool frame"),
    ("object_up", _XYZ, ("1",) * 3, "the object's up axis, tool frame"),
]
"""The 22 floats both environments start their observation with: ``(field, names, units, doc)``."""
PANCAKE_FIELDS = _fields(COMMON_FIELDS + [
    ("spatula", PANCAKE_STATE.names, PANCAKE_STATE.units,
     "the pancake Deformer's state: y, z relative to PANCAKE_ORIGIN, roll θ unwrapped, and their rates"),
])
SLIDING_FIELDS = _fields(COMMON_FIELDS + [
    ("pan", SLIDING_STATE.names[:4], SLIDING_STATE.units[:4], "pan centre relative to PAN_ORIGIN, and its velocity"),
    ("object", SLIDING_STATE.names[4:], SLIDING_STATE.units[4:], "object relative to the pan centre, pan frame"),
])


def _layout(fields: dict[str, Field], kind: str) -> StateLayout:
    names = tuple(f"{name}.{part}" for name, f in fields.items() for part in f.names)
    units = tuple(u for f in fields.values() for u in f.units)
    return StateLayout(names, units, kind)


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


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def _finite(value: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {shape[0]} numbers, got {value!r}") from None
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be {shape[0]} finite numbers, got {value!r}")
    return arr


def _refuse_unknown(cls: type, given: dict[str, Any]) -> None:
    """``ValueError`` naming each keyword ``cls`` does not take and listing those it does (a user writes
    ``action_mode="accel"`` for ``action="accel"``: Python's own TypeError names none of the valid ones)."""
    if not given:
        return
    valid = [name for name, p in inspect.signature(cls.__init__).parameters.items()
             if p.kind == inspect.Parameter.KEYWORD_ONLY]
    hints = []
    for name in sorted(given):
        close = difflib.get_close_matches(name, valid, n=1) or [v for v in valid if v in name]
        hints.append(f"{name!r}" + (f" (did you mean {close[0]}=?)" if close else ""))
    raise ValueError(f"{cls.__name__} takes no keyword {', '.join(hints)}; its keywords are {', '.join(valid)}")


class _ArmEnv(gym.Env):
    """Shared machinery: the arm, its controller, the three action modes, the observation."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}  # per instance: 1 / dt
    kind = ""
    fields: dict[str, Field] = {}
    model_layout: StateLayout = StateLayout(("none",), ("1",))
    model_fields: tuple[str, ...] = ()
    _options: tuple[str, ...] = ()

    def __init__(self, *, gains: str, frame_skip: int, action: str, normalize_actions: bool,
                 time_limit: float | None, render_mode: str | None, camera: str, width: int, height: int,
                 robot: str | Robot | None = None) -> None:
        if isinstance(frame_skip, bool) or not isinstance(frame_skip, int | np.integer) or frame_skip < 1:
            raise ValueError(f"frame_skip must be a positive integer, got {frame_skip!r}")
        if action not in ACTIONS:
            raise ValueError(f"action must be one of {ACTIONS}, got {action!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if time_limit is not None and not (np.isfinite(time_limit) and time_limit > 0):
            raise ValueError(f"time_limit must be a positive number of seconds or None, got {time_limit!r}")
        self._mj = import_mujoco()
        self.robot: Robot | None = resolve_robot(robot)  # None: the built-in arm ("mh3f" too)
        self.scene = get_scene(self.kind, self.robot)
        self.gains = resolve_gains(gains)
        self.frame_skip = int(frame_skip)
        self.action_mode = action
        self.normalize_actions = bool(normalize_actions)
        self.time_limit = None if time_limit is None else float(time_limit)
        self.render_mode = render_mode
        fps = 1.0 / self.dt
        self.metadata = {**type(self).metadata, "render_fps": int(round(fps)) if abs(fps - round(fps)) < 1e-9 else fps}
        self._camera, self._size = camera, (width, height)
        self._renderer: Renderer | None = None
        self.arm = Arm(self.scene, self.gains)
        self.data = self.arm.data  # the arm's MjData, stepped in place
        self.observation_layout = _layout(self.fields, f"{type(self).__name__} observation")
        dim = self.observation_layout.dim
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float64)
        low, high, self.action_layout = self._physical_action_space()
        self.physical_action_space = spaces.Box(low, high, dtype=np.float64)
        self._centre, self._half = (low + high) / 2, (high - low) / 2
        if self.normalize_actions:
            self.action_space = spaces.Box(-1.0, 1.0, shape=low.shape, dtype=np.float64)
        else:
            self.action_space = self.physical_action_space
        self._model_slice = slice(self.fields[self.model_fields[0]].slice.start,
                                  self.fields[self.model_fields[-1]].slice.stop)
        self._pos = np.zeros(3)
        self._quat = np.array([1.0, 0.0, 0.0, 0.0])
        self._ref = np.zeros(2 * self._task_dim)
        self._theta = 0.0
        self._steps = 0
        self._not_ready = "reset() has not been called yet"

    # -- subclasses define these -------------------------------------------------------------
    _task_dim = 0  # positions in the task's own coordinates (pancake: y, z, θ; sliding: x_p, y_p)

    def _physical_action_space(self) -> tuple[np.ndarray, np.ndarray, StateLayout]:
        raise NotImplementedError

    def _start(self, options: dict) -> np.ndarray:  # (task_dim,) start in task coordinates
        raise NotImplementedError

    def _place(self, options: dict) -> Place:
        raise NotImplementedError

    def _load(self) -> np.ndarray:
        raise NotImplementedError

    def _reward(self, obj_pos: np.ndarray) -> tuple[float, bool, dict]:  # object centre in the tool frame
        raise NotImplementedError

    def _planar_to_pose(self, p: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _planar_command(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # → site position, quaternion
        raise NotImplementedError

    def _lift(self, v: np.ndarray) -> np.ndarray:  # (task_dim,) rates → (6,) world [linear, angular]
        raise NotImplementedError

    def _task_observation(self, tool_pos: np.ndarray, rot: np.ndarray, twist: np.ndarray,
                          obj_pos: np.ndarray, obj_vel: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    # -- timing, actions, observation layout ---------------------------------------------------
    @property
    def dt(self) -> float:
        """Simulated time of one :meth:`step`: ``frame_skip`` control periods [s]."""
        return self.frame_skip * CONTROL_DT

    def to_physical(self, action: np.ndarray) -> np.ndarray:
        """An action of ``action_space`` in physical units (identity unless ``normalize_actions``)."""
        a = np.asarray(action, dtype=np.float64)
        return self._centre + self._half * a if self.normalize_actions else a

    def to_action(self, physical: np.ndarray) -> np.ndarray:
        """Physical units (``physical_action_space``) → an action of ``action_space``."""
        p = np.asarray(physical, dtype=np.float64)
        return (p - self._centre) / self._half if self.normalize_actions else p

    def field(self, obs: np.ndarray, name: str) -> np.ndarray:
        """``obs[..., fields[name].slice]``; ``KeyError`` naming the fields for an unknown name."""
        if name not in self.fields:
            raise KeyError(f"{type(self).__name__} has no observation field {name!r}; fields: {list(self.fields)}")
        return np.asarray(obs)[..., self.fields[name].slice]

    def model_state(self, obs: np.ndarray, model: Any = None) -> np.ndarray:
        """The model's state from observations ``(..., obs_dim)`` → ``(..., model_layout.dim)`` (a copy).

        PancakeArm: ``[y, z, θ, v_y, v_z, v_θ]`` (the pancake Deformer's); SlidingArm: ``[pan x, y,
        v_x, v_y, object x, y, v_x, v_y]`` (the sliding planner's). With ``model`` (anything with a
        ``state_layout``), ``ValueError`` unless that layout is this one.
        """
        if model is not None:
            theirs = getattr(model, "state_layout", None)
            if theirs is None or tuple(theirs.names) != self.model_layout.names:
                raise ValueError(f"{type(self).__name__} observes {self.model_layout}; "
                                 f"the model's state is {theirs}")
        obs = np.asarray(obs, dtype=np.float64)
        if obs.shape[-1:] != self.observation_space.shape:
            raise ValueError(f"obs must end in {self.observation_space.shape[0]} floats, got shape {obs.shape}")
        return obs[..., self._model_slice].copy()

    @property
    def reference(self) -> np.ndarray | None:
        """With ``action="accel"``: the commanded reference now, in ``model_layout``'s positions and
        velocities (pancake ``[y, z, θ, v_y, v_z, v_θ]``, sliding pan ``[x, y, v_x, v_y]``); else ``None``."""
        return self._ref.copy() if self.action_mode == "accel" else None

    @property
    def controller(self) -> TaskSpaceController | JointSpaceController | None:
        """The arm's controller (``None`` before the first :meth:`reset`): task space on the built-in arm,
        differential IK + joint space on a standard ``robot``."""
        return self.arm.controller

    # -- gymnasium API -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Start at rest with the object placed on the tool, settled for 20 ms.

        ``options``: PancakeArm ``start=(y, z, θ)`` [m, m, rad] (default the origin); SlidingArm
        ``goal=(x, y)`` [m] in the pan frame (default drawn within ``goal_radius``). A bad or
        unreachable option raises ``ValueError``, and :meth:`step` is refused until a reset succeeds.
        """
        self._not_ready = "the last reset() raised"
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = sorted(set(options) - set(self._options))
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; {type(self).__name__} takes {list(self._options)}")
        start = self._start(options)
        pos, quat = self._planar_command(start)
        if (problem := self._unreachable(pos, quat)) is not None:
            raise ValueError(f"the start pose is out of the arm's workspace: {problem}")
        place = self._place(options)
        self._pos, self._quat = pos, quat
        self._ref = np.concatenate([start, np.zeros(self._task_dim)])
        self._theta = float(start[2]) if self._task_dim == 3 else 0.0
        self.arm.reset(self._pos, self._quat, place, self._load())
        self._placed = self._relative()[0].copy()
        self._step_hold(20)  # let the object settle into contact (20 ms)
        self._steps = 0
        obs = self._observation()
        self._not_ready = ""
        return obs, {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Execute ``action`` (module docstring) for ``frame_skip`` control periods.

        Raises:
            ResetNeeded: before a successful :meth:`reset`, or after an episode ended out of the
                workspace or unstable.
            ValueError: an action of the wrong shape, or not finite.
        """
        if self._not_ready:
            raise ResetNeeded(f"call reset() before step(): {self._not_ready}")
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be finite with shape {self.action_space.shape}, got {a}")
        phys = self.to_physical(a)
        if self.action_mode == "accel":
            problem = self._step_accel(phys)
        else:
            problem = self._step_pose(self._planar_to_pose(phys) if self.action_mode == "planar" else phys)
        self._steps += 1
        obs = self._observation()
        reward, terminated, info = self._reward(obs[self.fields["object_pos"].slice])
        if isinstance(self.controller, JointSpaceController):  # what the robot's IK and torque limits allowed
            info["ik_error"], info["torque_saturated"] = self.controller.ik_error.copy(), self.controller.saturated
        if problem is not None:
            terminated, info["out_of_workspace"] = True, problem
            self._not_ready = f"the episode ended: the command left the arm's workspace ({problem})"
        elif self.arm.diverged() or not np.all(np.isfinite(self.data.qpos)):
            terminated, info["unstable"] = True, True
            self._not_ready = "the episode ended: the simulation became unstable"
        truncated = self.time_limit is not None and self._steps * self.dt >= self.time_limit - 1e-9
        return obs, float(reward), bool(terminated), bool(truncated), info

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
    def _unreachable(self, pos: np.ndarray, quat: np.ndarray) -> str | None:
        """Why the arm cannot reach the tool pose ``pos`` ``(3,)``, ``quat`` ``(4,)``, or ``None``."""
        zero = np.zeros((1, 3))
        ref = Reference(pos=pos[None], quat=quat[None], vel=zero, omega=zero, acc=zero, alpha=zero, n_motion=1)
        problem = workspace_problem(ref, self.kind, self.robot)
        return None if problem is None else problem.split(": ", 1)[-1]

    def _step_pose(self, pose: np.ndarray) -> str | None:
        """Move the command linearly to ``pose`` over the step (velocity fed forward)."""
        pos1, quat1 = pose[:3], matrix_to_quat(attitude_matrix(pose[3:]))
        if (problem := self._unreachable(pos1, quat1)) is not None:
            return problem
        duration = self.frame_skip * CONTROL_DT
        twist = np.concatenate([(pos1 - self._pos) / duration, _angular_velocity(self._quat, quat1, duration)])
        still = np.zeros(6)
        for i in range(1, self.frame_skip + 1):
            s = i / self.frame_skip
            self.arm.step(self._pos + s * (pos1 - self._pos), _slerp(self._quat, quat1, s), twist, still)
        self._pos, self._quat = pos1.copy(), quat1
        return None

    def _step_accel(self, accel: np.ndarray) -> str | None:
        """Integrate the reference under ``accel`` for the step, feeding pose, velocity and ``accel`` forward."""
        n = self._task_dim
        refs = integrate_numpy(self._ref, np.tile(accel, (self.frame_skip, 1)), CONTROL_DT)
        end_pos, end_quat = self._planar_command(refs[-1][:n])
        if (problem := self._unreachable(end_pos, end_quat)) is not None:
            return problem
        lifted = self._lift(accel)
        for x in refs[:-1]:
            pos, quat = self._planar_command(x[:n])
            self.arm.step(pos, quat, self._lift(x[n:]), lifted)
        self._ref = refs[-1].copy()
        self._pos, self._quat = end_pos, end_quat
        return None

    def _step_hold(self, steps: int) -> None:
        """Hold the current command for ``steps`` control periods."""
        still = np.zeros(6)
        for _ in range(steps):
            self.arm.step(self._pos, self._quat, still, still)

    def _relative(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Object position, velocity and up axis in the tool frame (recomputes the kinematics)."""
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
        obj_pos, obj_vel, up = self._relative()  # fresh kinematics first: the twist's Jacobian reads them
        twist = self.controller.tool_twist(d)
        tool_pos, rot = d.site_xpos[sc.site].copy(), d.site_xmat[sc.site].reshape(3, 3)
        task = self._task_observation(tool_pos, rot, twist, obj_pos, obj_vel)
        return np.concatenate([tool_pos, d.site_xquat[sc.site], twist, obj_pos, obj_vel, up, task]).astype(np.float64)


class PancakeArmEnv(_ArmEnv):
    """Keep the pancake on the spatula (chs. 2, 4 scene).

    Reward 1 per step while the pancake keeps contact (slip < 5 mm from where it was placed and
    gap < 2 mm: :data:`~seqmotion.sim.pancake.SLIP_LIMIT`, :data:`~seqmotion.sim.pancake.GAP_LIMIT`),
    else 0; the episode terminates once the pancake is off the blade. ``info``: ``slip``, ``gap``
    [m], ``in_contact``. ``reset(options=...)`` accepts ``start=(y, z, θ)``; the pancake is placed
    within ±``jitter`` m of the blade centre. Observation, actions, timing: the module docstring.

    Args:
        gains: controller gains preset (``"ch2"``, ``"ch3"``, ``"ch4"``).
        frame_skip: 1 ms control periods per step (``dt = frame_skip × 1 ms``).
        action: the action mode, ``"planar"`` (default), ``"accel"`` or ``"pose"`` (the keyword is ``action=``;
            an unknown keyword such as ``action_mode=`` is refused by name, listing the valid ones).
        normalize_actions: ``Box(-1, 1)`` actions mapped onto the physical bounds.
        jitter: [m]. time_limit: episode length [s] (``None``: none).
        render_mode: ``None`` or ``"rgb_array"``; camera, width, height: of the rendered frames.
        robot: a standard arm (``"panda"``, ``"ur5e"``, ``"menagerie:<name>"``, …: :func:`seqmotion.sim.robots`)
            driven by differential IK + joint-space PD + DOB (``info`` then holds ``ik_error`` [m, rad] and
            ``torque_saturated``), or a :class:`~seqmotion.sim.robot_models.Robot`; ``None`` (default) or
            ``"mh3f"``: the built-in arm. :attr:`robot` holds it resolved (the ``Robot``, or ``None``).
    """

    kind = "pancake"
    fields = PANCAKE_FIELDS
    model_layout = PANCAKE_STATE
    model_fields = ("spatula",)
    _options = ("start",)
    _task_dim = 3

    def __init__(self, *, gains: str = "ch2", frame_skip: int = 10, action: str = "planar",
                 normalize_actions: bool = False, jitter: float = 0.005, time_limit: float | None = TIME_LIMIT,
                 render_mode: str | None = None, camera: str = "oblique", width: int = 480,
                 height: int = 360, robot: str | Robot | None = None, **unknown: Any) -> None:
        _refuse_unknown(type(self), unknown)
        self.jitter = float(jitter)
        super().__init__(gains=gains, frame_skip=frame_skip, action=action, normalize_actions=normalize_actions,
                         time_limit=time_limit, render_mode=render_mode, camera=camera, width=width, height=height,
                         robot=robot)

    def _physical_action_space(self) -> tuple[np.ndarray, np.ndarray, StateLayout]:
        if self.action_mode == "planar":
            bound = np.array([0.35, 0.35, 2 * np.pi])
            return -bound, bound, StateLayout(PANCAKE_STATE.names[:3], PANCAKE_STATE.units[:3], "spatula pose")
        if self.action_mode == "accel":
            bound = np.array([40.0, 40.0, 500.0])
            return -bound, bound, PANCAKE_ACCEL
        low = np.concatenate([PANCAKE_ORIGIN - 0.35, [-2 * np.pi, 0.0, -np.pi]])
        high = np.concatenate([PANCAKE_ORIGIN + 0.35, [2 * np.pi, np.pi, np.pi]])
        return low, high, _POSE

    def _planar_to_pose(self, p: np.ndarray) -> np.ndarray:
        return np.array([PANCAKE_ORIGIN[0], PANCAKE_ORIGIN[1] + p[0], PANCAKE_ORIGIN[2] + p[1], p[2], TOOL_PITCH, 0.0])

    def _planar_command(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # matrix_to_quat(attitude_matrix([θ, π/2, 0])) in closed form (w ≥ 0): q_x(θ) ⊗ q_y(π/2)
        c, s = np.cos(0.5 * p[2]) * _SQRT_HALF, np.sin(0.5 * p[2]) * _SQRT_HALF
        quat = np.array([c, s, c, s]) if c >= 0 else np.array([-c, -s, -c, -s])
        return np.array([PANCAKE_ORIGIN[0], PANCAKE_ORIGIN[1] + p[0], PANCAKE_ORIGIN[2] + p[1]]), quat

    def _lift(self, v: np.ndarray) -> np.ndarray:
        return np.array([0.0, v[0], v[1], v[2], 0.0, 0.0])

    def _start(self, options: dict) -> np.ndarray:
        return _finite(options.get("start", (0.0, 0.0, 0.0)), (3,), "start (y, z, θ)")

    def _place(self, options: dict) -> Place:
        offset = self.np_random.uniform(-self.jitter, self.jitter, size=2)
        return place_on_tool(self.scene, 0.0, offset)

    def _load(self) -> np.ndarray:
        return weight(PANCAKE_MASS)

    def _task_observation(self, tool_pos, rot, twist, obj_pos, obj_vel) -> np.ndarray:
        self._theta += _wrap(float(planar_tilt(rot)) - self._theta)  # unwrapped: continuous over the episode
        return np.array([tool_pos[1] - PANCAKE_ORIGIN[1], tool_pos[2] - PANCAKE_ORIGIN[2], self._theta,
                         twist[1], twist[2], twist[3]])

    def _reward(self, pos: np.ndarray) -> tuple[float, bool, dict]:
        slip = float(np.linalg.norm(pos[1:] - self._placed[1:]))
        gap = float(max(0.0, -pos[0]))
        in_contact = slip < SLIP_LIMIT and gap < GAP_LIMIT
        off = gap > 0.03 or abs(pos[1]) > BLADE_HALF[1] or abs(pos[2]) > BLADE_HALF[2]
        return (1.0 if in_contact else 0.0), off, {"slip": slip, "gap": gap, "in_contact": in_contact}


class SlidingArmEnv(_ArmEnv):
    """Slide the object on the frying pan to a goal in the pan frame (ch. 3 scene).

    Reward ``-|p_object - goal|`` [m] per step (pan frame, planar); the episode terminates if
    the object leaves the pan. ``info``: ``distance`` [m], ``object``, ``goal``. ``reset(options=...)``
    accepts ``goal=(x, y)``; otherwise the goal is drawn uniformly within ``goal_radius`` of the pan
    centre. The object starts at rest at the centre. Arguments as :class:`PancakeArmEnv`'s.
    """

    kind = "sliding"
    fields = SLIDING_FIELDS
    model_layout = SLIDING_STATE
    model_fields = ("pan", "object")
    _options = ("goal",)
    _task_dim = 2

    def __init__(self, *, gains: str = "ch3", frame_skip: int = 10, action: str = "planar",
                 normalize_actions: bool = False, goal_radius: float = 0.06, time_limit: float | None = TIME_LIMIT,
                 render_mode: str | None = None, camera: str = "front", width: int = 480,
                 height: int = 360, robot: str | Robot | None = None, **unknown: Any) -> None:
        _refuse_unknown(type(self), unknown)
        self.goal_radius = float(goal_radius)
        self.goal = np.zeros(2)
        super().__init__(gains=gains, frame_skip=frame_skip, action=action, normalize_actions=normalize_actions,
                         time_limit=time_limit, render_mode=render_mode, camera=camera, width=width, height=height,
                         robot=robot)

    def _physical_action_space(self) -> tuple[np.ndarray, np.ndarray, StateLayout]:
        if self.action_mode == "planar":
            bound = np.array([0.2, 0.2])
            return -bound, bound, StateLayout(SLIDING_STATE.names[:2], SLIDING_STATE.units[:2], "pan position")
        if self.action_mode == "accel":
            bound = np.array([20.0, 20.0])
            return -bound, bound, PAN_ACCEL
        low = np.concatenate([PAN_ORIGIN - 0.2, [-np.pi, 0.0, -np.pi]])
        high = np.concatenate([PAN_ORIGIN + 0.2, [np.pi, np.pi, np.pi]])
        return low, high, _POSE

    def _planar_to_pose(self, p: np.ndarray) -> np.ndarray:
        return np.array([PAN_ORIGIN[0] + p[0], PAN_ORIGIN[1] + p[1], PAN_ORIGIN[2], 0.0, TOOL_PITCH, 0.0])

    def _planar_command(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.array([PAN_ORIGIN[0] + p[0], PAN_ORIGIN[1] + p[1], PAN_ORIGIN[2]]), _PAN_QUAT.copy()

    def _lift(self, v: np.ndarray) -> np.ndarray:
        return np.array([v[0], v[1], 0.0, 0.0, 0.0, 0.0])

    def _start(self, options: dict) -> np.ndarray:
        return np.zeros(2)

    def _place(self, options: dict) -> Place:
        if "goal" in options:
            goal = _finite(options["goal"], (2,), "goal (x, y)")
            if np.hypot(*goal) > PAN_RADIUS - 0.04:
                raise ValueError(f"goal {goal.tolist()} m is not on the pan (radius {PAN_RADIUS} m)")
            self.goal = goal
        else:
            r = self.goal_radius * np.sqrt(self.np_random.uniform())
            phi = self.np_random.uniform(-np.pi, np.pi)
            self.goal = np.array([r * np.cos(phi), r * np.sin(phi)])
        return place_on_tool(self.scene, OBJECT_HALF_HEIGHT, np.zeros(2))

    def _load(self) -> np.ndarray:
        return weight(OBJECT_MASS)

    def _task_observation(self, tool_pos, rot, twist, obj_pos, obj_vel) -> np.ndarray:
        return np.array([tool_pos[0] - PAN_ORIGIN[0], tool_pos[1] - PAN_ORIGIN[1], twist[0], twist[1],
                         obj_pos[2], obj_pos[1], obj_vel[2], obj_vel[1]])

    def _reward(self, pos: np.ndarray) -> tuple[float, bool, dict]:
        planar = pos[[2, 1]]
        height = -pos[0] - OBJECT_HALF_HEIGHT
        off = bool(np.linalg.norm(planar) > PAN_RADIUS + 0.01 or height < -0.01)
        dist = float(np.linalg.norm(planar - self.goal))
        return -dist, off, {"distance": dist, "object": planar, "goal": self.goal.copy()}


_SQRT_HALF = float(np.sqrt(0.5))
_PAN_QUAT = matrix_to_quat(attitude_matrix(np.array([0.0, TOOL_PITCH, 0.0])))
_POSE = StateLayout(("x", "y", "z", "a", "b", "c"), ("m", "m", "m", "rad", "rad", "rad"), "tool pose")

__all__ = ["ACTIONS", "Field", "PancakeArmEnv", "ResetNeeded", "SlidingArmEnv", "TIME_LIMIT",
           "PANCAKE_FIELDS", "SLIDING_FIELDS"]
