"""A robot's parallel pitch joints as a planar chain in the pancake's task plane, and their limits as constraints
of the exact polish: :func:`planar_chain`, :func:`chain_joint_speeds`, :func:`arm_form`.

Why: keeping a pancake on an inverted spatula needs a loop (centripetal acceleration Ω²R ≥ ≈ 1.05 g at μ = 1), and
no single wrist joint at its rated speed can turn the spatula fast enough for one (the UR5e's wrist 3 at π rad/s
needs R ≥ 0.99 m). Where the arm stands so that several of its joints turn about axes parallel to the task's θ axis
(world x: the UR5e's shoulder lift, elbow and wrist 1; the Panda's joints 2, 4 and 6 with 1, 3 and 5 held at 0;
:data:`~seqmotion.sim.placements.PLACEMENTS`), their speeds add up about one axis (3 × π rad/s; 6.96 rad/s), and
the spatula's (y, z, θ) is a planar three-link chain of them with every other joint held still: the generator's
planar motion *is* the arm's joint path.

The chain (task-plane coordinates: ``y`` = world y, ``z`` = world z − 0.35 m, the pancake's origin at (0, 0)):
the shoulder's axis at ``S``, the elbow's at ``E`` (``|E − S| = upper``), the third joint's at ``W``
(``|W − E| = fore``), and the spatula's site at ``P``, with ``W = P + R(θ) w0`` for the fixed offset ``w0`` of the
third joint from the site at θ = 0. Given (y, z, θ) the elbow follows in closed form (the branch the robot's home is
on), and given the velocities the three joint speeds follow from the chain's Jacobian:

    Ẇ = v + θ̇ J R(θ) w0,    [J(E − S)  J(W − E)] [ω₁, ω₂]ᵀ = Ẇ,    q̇ = (ω₁, ω₂ − ω₁, θ̇ − ω₂)

(``J`` the quarter turn, ``ω`` the links' angular rates). These are exact for the arm in MuJoCo: the same joint
values the simulator's IK reaches (``tests/test_robot_limits.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from ..core.polish import ArmForm
from ..physics.transcription import Constraint, JointSpace, casadi, input_limits
from .backend import import_mujoco
from .limits import JointLimits
from .robot_models import Robot, resolve_robot
from .scene import PANCAKE_ORIGIN, TABLE_CLEARANCE, TABLE_TOP, get_scene

PARALLEL_TOLERANCE = 1e-6
"""A joint's axis counts as parallel to the task's θ axis (world x) when ``|axis · x| ≥ 1 − this``."""

SINGULARITY_CLEARANCE = 0.05
"""[m] The flange's centre (the last joint's axis) stays this far from the vertical line of the base joint's axis,
on the home's side. A 6-R arm whose wrist centre passes over its base axis is at its shoulder singularity: on the
UR5e the simulator's IK swung the base joint at 16 rad/s there (its Jacobian's smallest singular value 0.004 m at
3 mm), and even 0.08 m away it is only 0.03."""

SPEED_MARGIN = 0.95
"""The polish keeps the chain's joint speeds within this share of the rated ones: the arm tracking the motion under
PD control with a disturbance observer runs a little faster than planned where the motion brakes hard (1.003 of the
rated speed for 6 ms on a plan at 0.97; 1.01 for 145 ms on one at 0.99)."""

IPOPT_OPTIONS = (("ipopt.mu_strategy", "adaptive"),)
"""IPOPT's options for the polish on the joints: its adaptive barrier update took 97 iterations where the monotone
default took 126 on the README's turn (the start is far from feasible: a motion about a fixed point, not a loop)."""

TORQUE_MARGIN = 0.8
"""The polish keeps the torques the motion needs (:func:`chain_torques`) within this share of the model's limits: the
rest is the controller's, whose feedback and disturbance observer add to the feedforward while tracking."""

ELBOW_MARGIN = 0.03
"""[rad] The chain's elbow keeps this far from stretched and from folded (its links' relative angle within
[margin, π − margin] on its home's side): the closed-form IK the simulator follows the chain with
(:func:`chain_joints`) takes the home's elbow branch, and the controller's feedforward goes through the arm's
Jacobian, singular there (a differential IK asked the shoulder for 5.7 rad/s by a stretched elbow)."""

TABLE_MARGIN = 0.01
"""[m] The polish keeps the spatula's site this far above the simulator's lowest allowed pose
(:data:`~seqmotion.sim.scene.TABLE_CLEARANCE` over the table top): the loops a turn needs swing it down toward it."""

JOINT_HOLD = 4
"""The polish holds the joints' accelerations over this many 1 ms samples (its knots, :class:`~seqmotion.core.polish
.ArmForm`): four times fewer variables, and IPOPT ~4× faster; the friction cone, imposed at the knots with the polish's
normal-force floor, still held at every sample of the README's turns."""


@dataclass(frozen=True)
class PlanarChain:
    """Three arm joints with axes along world x, holding the spatula's site, as a planar chain (any joint between
    them held at home).

    Attributes:
        robot: the robot, ``"name (source)"``.
        joints: the three joints' names (shoulder, elbow, wrist), base → flange.
        index: their positions among the arm's joints.
        shoulder: ``(2,)`` the first joint's axis in the task plane (y, z) [m].
        upper: distance between the first and second axes [m].
        fore: distance between the second and third axes [m].
        wrist: ``(2,)`` the third axis relative to the site at θ = 0 [m] (``w0``).
        elbow: ``+1`` or ``-1``: which side of the shoulder–wrist line the elbow is on (the home's).
        home: ``(n,)`` the arm's posture at the pancake's origin [rad]; every joint but the three stays there.
        axis_sign: ``(3,)`` ±1: each joint's axis along +x or −x (a joint turns θ by ``axis_sign`` × its angle).
        flange: ``(2,)`` the flange's centre (the last arm joint's axis) relative to the site at θ = 0 [m].
        base_line: the y [m] of the base joint's vertical axis in the task plane, or ``None`` (no vertical base
            joint): the flange's centre stays :data:`SINGULARITY_CLEARANCE` from it on the side it starts
            (``base_side``, ±1).
        link_mass, link_com, link_inertia: ``(3,)`` [kg], ``(3, 2)`` [m] and ``(3,)`` [kg m²]: each link's mass,
            centre of mass relative to its joint's axis at home, and inertia about x through it (the last link with
            the wrist's other joints and the tool).
        damping, armature: ``(3,)`` the joints' damping [N m s/rad] and armature [kg m²] in the model.
        gravity: the model's gravity along z [m/s²] (negative).
    """

    robot: str
    joints: tuple[str, str, str]
    index: tuple[int, int, int]
    shoulder: np.ndarray
    upper: float
    fore: float
    wrist: np.ndarray
    elbow: float
    home: np.ndarray
    axis_sign: np.ndarray
    flange: np.ndarray
    base_line: float | None
    base_side: float
    link_mass: np.ndarray
    link_com: np.ndarray
    link_inertia: np.ndarray
    damping: np.ndarray
    armature: np.ndarray
    gravity: float

    @property
    def reach(self) -> tuple[float, float]:
        """The shoulder–wrist distances [m] of the elbow :data:`ELBOW_MARGIN` from folded and from stretched: the polish
        keeps the elbow within them (:func:`joint_space`), so the closed-form IK (:func:`chain_joints`) of any pose it
        plans is exact, and pulls a pose out of them back in."""
        square, cross = self.upper**2 + self.fore**2, 2 * self.upper * self.fore * math.cos(ELBOW_MARGIN)
        return math.sqrt(square - cross), math.sqrt(square + cross)


def planar_chain(robot: str | Robot | None) -> PlanarChain | None:
    """The robot's planar chain in the pancake scene (:class:`PlanarChain`), or ``None`` where its placement has no
    three joints along the task's θ axis holding the site (the built-in arm's, which turns it with its wrist)."""
    standard = resolve_robot(robot)
    if standard is None:
        return None
    return _chain(standard)


@lru_cache(maxsize=8)
def _chain(robot: Robot) -> PlanarChain | None:
    mujoco = import_mujoco()
    scene = get_scene("pancake", robot)
    m = scene.model
    data = mujoco.MjData(m)
    data.qpos[scene.arm_qpos] = robot.home
    mujoco.mj_forward(m, data)
    joint_ids = [int(m.dof_jntid[d]) for d in scene.arm_dof]
    along_x = [k for k, j in enumerate(joint_ids) if abs(data.xaxis[j][0]) >= 1 - PARALLEL_TOLERANCE]
    if len(along_x) < 3:
        return None
    # The three nearest the flange carry the tool. Joints between them (the Panda's 3 and 5, along its links) are
    # held at home, which keeps each link between two chain axes rigid: the chain stays planar.
    index = tuple(along_x[-3:])
    origin = np.array([PANCAKE_ORIGIN[1], PANCAKE_ORIGIN[2]])
    anchors = [data.xanchor[joint_ids[k]][1:] - origin for k in index]
    site = data.site_xpos[scene.site][1:] - origin
    shoulder, elbow_at, wrist = (np.asarray(a, dtype=np.float64) for a in anchors)
    d = wrist - shoulder
    side = float(np.sign(_cross(d, elbow_at - shoulder)))
    if side == 0.0:
        return None  # a stretched arm at home: no branch to follow
    names = tuple(m.joint(joint_ids[k]).name.split("/")[-1] for k in index)
    flange = data.xanchor[joint_ids[-1]][1:] - origin
    base = joint_ids[0]
    base_line = float(data.xanchor[base][1] - origin[0]) if abs(data.xaxis[base][2]) >= 1 - PARALLEL_TOLERANCE else None
    base_side = 1.0 if base_line is None or flange[0] >= base_line else -1.0
    chain = PlanarChain(
        robot=robot.label, joints=names, index=index, shoulder=shoulder,
        upper=float(np.linalg.norm(elbow_at - shoulder)), fore=float(np.linalg.norm(wrist - elbow_at)),
        wrist=wrist - site, elbow=side, home=np.array(robot.home, dtype=np.float64),
        axis_sign=np.sign([data.xaxis[joint_ids[k]][0] for k in index]), flange=flange - site,
        base_line=base_line, base_side=base_side,
        **_link_dynamics(m, data, [joint_ids[k] for k in index], [scene.arm_dof[k] for k in index], anchors),
    )
    return chain


def _link_dynamics(m: Any, data: Any, joints: list[int], dofs: list[int], anchors: list[np.ndarray]) -> dict:
    """The three links' planar inertia at home, from the model: each link is every body whose nearest chain joint
    above it is that joint (the tool with the last), its mass [kg], its centre of mass relative to its joint's axis
    in the task plane [m], and its moment of inertia about x through that centre [kg m²]; the joints' damping
    [N m s/rad] and armature [kg m²]; gravity along z [m/s²]."""
    group = np.full(m.nbody, -1)
    for b in range(1, m.nbody):
        a = b
        while a > 0 and group[b] < 0:
            adr, num = int(m.body_jntadr[a]), int(m.body_jntnum[a])
            for k in (2, 1, 0):
                if num > 0 and adr <= joints[k] < adr + num:
                    group[b] = k
                    break
            a = int(m.body_parentid[a])
    origin = np.array([PANCAKE_ORIGIN[1], PANCAKE_ORIGIN[2]])
    mass, com, inertia = np.zeros(3), np.zeros((3, 2)), np.zeros(3)
    for k in range(3):
        bodies = np.flatnonzero(group == k)
        masses = m.body_mass[bodies]
        points = data.xipos[bodies][:, 1:] - origin
        mass[k] = masses.sum()
        centre = (masses[:, None] * points).sum(axis=0) / max(mass[k], 1e-12)
        own = [(data.ximat[b].reshape(3, 3) @ np.diag(m.body_inertia[b]) @ data.ximat[b].reshape(3, 3).T)[0, 0]
               for b in bodies]
        inertia[k] = float(np.sum(own) + np.sum(masses * np.sum((points - centre) ** 2, axis=1)))
        com[k] = centre - anchors[k]
    return {"link_mass": mass, "link_com": com, "link_inertia": inertia,
            "damping": np.array(m.dof_damping[dofs], dtype=np.float64),
            "armature": np.array(m.dof_armature[dofs], dtype=np.float64), "gravity": float(m.opt.gravity[2])}


def chain_torques(chain: PlanarChain, q: Any, qd: Any, qdd: Any, cos: Any = np.cos, sin: Any = np.sin) -> list:
    """The three joints' torques [N m] that move the chain along joint angles, speeds and accelerations (rows of
    three, NumPy or CasADi), every other joint held at home: the links' planar Newton–Euler equations with gravity,
    plus the joints' damping and armature — MuJoCo's inverse dynamics (``mj_inverse``) of the same motion, without
    the pancake's contact."""
    sign, home = chain.axis_sign, chain.home[list(chain.index)]
    d = [float(sign[j]) * (q[j] - float(home[j])) for j in range(3)]
    dd = [float(sign[j]) * qd[j] for j in range(3)]
    ddd = [float(sign[j]) * qdd[j] for j in range(3)]
    beta = [d[0], d[0] + d[1], d[0] + d[1] + d[2]]
    rate = [dd[0], dd[0] + dd[1], dd[0] + dd[1] + dd[2]]
    accel = [ddd[0], ddd[0] + ddd[1], ddd[0] + ddd[1] + ddd[2]]
    cb, sb = [cos(b) for b in beta], [sin(b) for b in beta]

    def turned(k: int, v: np.ndarray) -> tuple[Any, Any]:
        return cb[k] * float(v[0]) - sb[k] * float(v[1]), sb[k] * float(v[0]) + cb[k] * float(v[1])

    def point_accel(k: int, v: np.ndarray) -> tuple[Any, Any]:  # d²/dt² of R(β_k) v
        ry, rz = turned(k, v)
        return -accel[k] * rz - rate[k] ** 2 * ry, accel[k] * ry - rate[k] ** 2 * rz

    e0 = _home_elbow(chain) - chain.shoulder  # the links' axis-to-axis vectors at home
    f0 = chain.wrist - _home_elbow(chain)
    anchor = [(float(chain.shoulder[0]), float(chain.shoulder[1]))]
    ey, ez = turned(0, e0)
    anchor.append((anchor[0][0] + ey, anchor[0][1] + ez))
    fy, fz = turned(1, f0)
    anchor.append((anchor[1][0] + fy, anchor[1][1] + fz))
    a1 = point_accel(0, e0)
    f_acc = point_accel(1, f0)
    anchor_accel = [(0.0, 0.0), a1, (a1[0] + f_acc[0], a1[1] + f_acc[1])]
    centre, force = [], []
    for k in range(3):
        cy, cz = turned(k, chain.link_com[k])
        ay, az = point_accel(k, chain.link_com[k])
        centre.append((anchor[k][0] + cy, anchor[k][1] + cz))
        mass = float(chain.link_mass[k])
        force.append((mass * (anchor_accel[k][0] + ay), mass * (anchor_accel[k][1] + az - chain.gravity)))
    torques = []
    for j in range(3):
        tau = 0
        for k in range(j, 3):
            ry, rz = centre[k][0] - anchor[j][0], centre[k][1] - anchor[j][1]
            tau = tau + ry * force[k][1] - rz * force[k][0] + float(chain.link_inertia[k]) * accel[k]
        torques.append(float(sign[j]) * tau + float(chain.damping[j]) * qd[j] + float(chain.armature[j]) * qdd[j])
    return torques


def _home_elbow(chain: PlanarChain) -> np.ndarray:
    """The elbow's axis in the task plane at home [m]."""
    d = chain.wrist - chain.shoulder
    dist = float(np.linalg.norm(d))
    along = (dist**2 + chain.upper**2 - chain.fore**2) / (2 * dist)
    across = chain.elbow * math.sqrt(max(chain.upper**2 - along**2, 0.0))
    return chain.shoulder + (along * d + across * np.array([-d[1], d[0]])) / dist


def _cross(a: Any, b: Any) -> Any:
    """The 2-D cross product ``a_y b_z − a_z b_y`` (NumPy ``(..., 2)`` arrays or CasADi pairs)."""
    return a[0] * b[1] - a[1] * b[0]


def _speeds(chain: PlanarChain, y: Any, z: Any, theta: Any, vy: Any, vz: Any, vtheta: Any,
            sqrt: Any, cos: Any, sin: Any, fmax: Any) -> tuple[Any, Any, Any, Any]:
    """The three joint speeds [rad/s] (as rates of the links' angles: each joint's axis sign aside) and the
    shoulder–wrist distance [m], in NumPy or CasADi (``sqrt``, ``cos``, … are the library's)."""
    w0y, w0z = float(chain.wrist[0]), float(chain.wrist[1])
    sy, sz = float(chain.shoulder[0]), float(chain.shoulder[1])
    l1, l2 = chain.upper, chain.fore
    c, s = cos(theta), sin(theta)
    rwy, rwz = c * w0y - s * w0z, s * w0y + c * w0z  # R(θ) w0
    wy, wz = y + rwy, z + rwz
    cy, cz = vy - vtheta * rwz, vz + vtheta * rwy  # Ẇ = v + θ̇ J R(θ) w0
    dy, dz = wy - sy, wz - sz
    dist = sqrt(dy**2 + dz**2)
    along = (dist**2 + l1**2 - l2**2) / (2 * dist)
    across = chain.elbow * sqrt(fmax(l1**2 - along**2, 0.0))
    ay, az = (along * dy - across * dz) / dist, (along * dz + across * dy) / dist  # E − S
    by, bz = dy - ay, dz - az  # W − E
    det = ay * bz - az * by
    w1 = (cy * by + cz * bz) / det
    w2 = -(ay * cy + az * cz) / det
    return w1, w2 - w1, vtheta - w2, dist


def chain_joint_speeds(chain: PlanarChain, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The chain's joint speeds ``(K, 3)`` [rad/s] (signed as the joints turn) and shoulder–wrist distances ``(K,)``
    [m] along planar states ``(K, 6)``."""
    arr = np.asarray(states, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        *speeds, dist = _speeds(chain, *arr.T, np.sqrt, np.cos, np.sin, np.maximum)
    return np.stack(speeds, axis=1) * chain.axis_sign, dist


def flange_clearance(chain: PlanarChain, states: Any, cos: Any = np.cos, sin: Any = np.sin) -> Any:
    """How far the flange's centre stays from the base joint's axis, on the home's side [m] (negative: across it),
    per sample of planar states ``(K, 6)`` (NumPy) or rows of a CasADi state matrix ``(6, K)``."""
    if chain.base_line is None:
        raise ValueError(f"{chain.robot}'s placement has no vertical base joint: no shoulder singularity to keep from")
    y, theta = (states[:, 0], states[:, 2]) if isinstance(states, np.ndarray) else (states[0, :], states[2, :])
    fy, fz = float(chain.flange[0]), float(chain.flange[1])
    return chain.base_side * (y + cos(theta) * fy - sin(theta) * fz - chain.base_line)


def link_angles(chain: PlanarChain) -> tuple[float, float]:
    """The upper and fore links' angles in the task plane at home [rad] (from +y toward +z)."""
    elbow = _home_elbow(chain)
    wrist = chain.wrist  # W − P at θ = 0, and P = 0 at home
    return (math.atan2(elbow[1] - chain.shoulder[1], elbow[0] - chain.shoulder[0]),
            math.atan2(wrist[1] - elbow[1], wrist[0] - elbow[0]))


def _forward(chain: PlanarChain, q: Any, qd: Any, qdd: Any, cos: Any, sin: Any) -> tuple[Any, ...]:
    """The site's (y, z, θ), its velocities and its accelerations from the chain's joint angles, speeds and
    accelerations (rows of three; NumPy or CasADi): exact planar forward kinematics and its time derivatives."""
    a1, a2 = link_angles(chain)
    sign, home = chain.axis_sign, chain.home[list(chain.index)]
    d = [float(sign[j]) * (q[j] - float(home[j])) for j in range(3)]
    dd = [float(sign[j]) * qd[j] for j in range(3)]
    ddd = [float(sign[j]) * qdd[j] for j in range(3)]
    p1, p2, th = a1 + d[0], a2 + d[0] + d[1], d[0] + d[1] + d[2]
    w1, w2, wt = dd[0], dd[0] + dd[1], dd[0] + dd[1] + dd[2]
    e1, e2, et = ddd[0], ddd[0] + ddd[1], ddd[0] + ddd[1] + ddd[2]
    l1, l2 = chain.upper, chain.fore
    w0y, w0z = float(chain.wrist[0]), float(chain.wrist[1])
    c1, s1, c2, s2, ct, st = cos(p1), sin(p1), cos(p2), sin(p2), cos(th), sin(th)
    ry, rz = ct * w0y - st * w0z, st * w0y + ct * w0z  # R(θ) w0
    y = float(chain.shoulder[0]) + l1 * c1 + l2 * c2 - ry
    z = float(chain.shoulder[1]) + l1 * s1 + l2 * s2 - rz
    vy = -l1 * w1 * s1 - l2 * w2 * s2 + wt * rz
    vz = l1 * w1 * c1 + l2 * w2 * c2 - wt * ry
    ay = l1 * (-e1 * s1 - w1**2 * c1) + l2 * (-e2 * s2 - w2**2 * c2) + et * rz + wt**2 * ry
    az = l1 * (e1 * c1 - w1**2 * s1) + l2 * (e2 * c2 - w2**2 * s2) - et * ry + wt**2 * rz
    return y, z, th, vy, vz, wt, ay, az, et


def chain_joints(chain: PlanarChain, states: np.ndarray) -> np.ndarray:
    """The chain's joint angles and speeds ``(K, 6)`` [rad, rad/s] along planar states ``(K, 6)``: closed-form
    inverse kinematics on the home's elbow branch, continuous in time. Out of reach, the wrist is pulled back
    within it (the result is then a start for the polish, not the pose)."""
    arr = np.asarray(states, dtype=np.float64)
    y, z, theta = arr[:, 0], arr[:, 1], arr[:, 2]
    w0y, w0z = chain.wrist
    c, s = np.cos(theta), np.sin(theta)
    w = np.stack([y + c * w0y - s * w0z, z + s * w0y + c * w0z], axis=1)
    d = w - chain.shoulder
    dist = np.linalg.norm(d, axis=1)
    inner, outer = chain.reach
    scale = np.clip(dist, inner, outer) / np.maximum(dist, 1e-12)
    d, dist = d * scale[:, None], np.clip(dist, inner, outer)
    along = (dist**2 + chain.upper**2 - chain.fore**2) / (2 * dist)
    across = chain.elbow * np.sqrt(np.maximum(chain.upper**2 - along**2, 0.0))
    e = chain.shoulder + (along[:, None] * d + across[:, None] * np.stack([-d[:, 1], d[:, 0]], axis=1)) / dist[:, None]
    wrist = chain.shoulder + d
    phi1 = np.unwrap(np.arctan2(e[:, 1] - chain.shoulder[1], e[:, 0] - chain.shoulder[0]))
    phi2 = np.unwrap(np.arctan2(wrist[:, 1] - e[:, 1], wrist[:, 0] - e[:, 0]))
    a1, a2 = link_angles(chain)
    delta = np.stack([phi1 - a1, (phi2 - a2) - (phi1 - a1), theta - (phi2 - a2)], axis=1)
    delta -= 2 * np.pi * np.round(delta[:1] / (2 * np.pi))  # the branch nearest home at the start
    speeds, _ = chain_joint_speeds(chain, arr)
    q = chain.home[list(chain.index)] + chain.axis_sign * delta
    return np.concatenate([q, np.nan_to_num(speeds)], axis=1)


def chain_task(chain: PlanarChain, joints: np.ndarray, joint_accel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planar states ``(K, 6)`` and the spatula's accelerations ``(K-1, 3)`` along the chain's joint states ``(K, 6)``
    and accelerations ``(K-1, 3)``: the arm's forward kinematics, exact at every sample."""
    joints, joint_accel = np.asarray(joints, np.float64), np.asarray(joint_accel, np.float64)
    padded = np.concatenate([joint_accel, np.zeros((1, 3))])
    *values, ay, az, at = _forward(chain, joints[:, :3].T, joints[:, 3:].T, padded.T, np.cos, np.sin)
    return np.stack(values, axis=1), np.stack([ay, az, at], axis=1)[:-1]


def joint_space(chain: PlanarChain, limits: JointLimits) -> JointSpace:
    """The chain's joints as the polish's variables (:class:`~seqmotion.physics.transcription.JointSpace`): rated
    speeds (:data:`SPEED_MARGIN` of them) and accelerations where known, joint ranges, the torques of the chain's
    inverse dynamics within :data:`TORQUE_MARGIN` of the model's limits, and the flange clear of the shoulder
    singularity, with the pancake's constraints on the forward kinematics."""
    ca = casadi()
    index = list(chain.index)
    speed = SPEED_MARGIN * limits.velocity[index]
    low = np.full(3, -np.inf) if limits.position is None else limits.position[index, 0].copy()
    high = np.full(3, np.inf) if limits.position is None else limits.position[index, 1].copy()
    # the elbow stays on its home's side, ELBOW_MARGIN from stretched and from folded: near either the simulator's
    # IK cannot follow the chain (a stretched elbow asked it for 5.7 rad/s at the shoulder)
    a1, a2 = link_angles(chain)
    bend = math.remainder(a2 - a1, 2 * math.pi)
    side = math.copysign(1.0, bend)
    ends = sorted(float(chain.home[index[1]]) + float(chain.axis_sign[1]) * (side * b - bend)
                  for b in (ELBOW_MARGIN, math.pi - ELBOW_MARGIN))
    low[1], high[1] = max(low[1], ends[0]), min(high[1], ends[1])
    bounds = (tuple(map(float, np.concatenate([low, -speed]))), tuple(map(float, np.concatenate([high, speed]))))
    constraints = []
    if limits.acceleration is not None:
        constraints.append(input_limits(tuple(SPEED_MARGIN * limits.acceleration[index]),
                                        f"{chain.robot}'s rated joint accelerations"))

    def to_task(x: Any, u: Any) -> tuple[Any, Any]:
        q, qd = [x[j, :] for j in range(3)], [x[3 + j, :] for j in range(3)]
        *values, _, _, _ = _forward(chain, q, qd, [0 * x[0, :]] * 3, ca.cos, ca.sin)
        head = [x[j, :-1] for j in range(6)]
        *_, ay, az, at = _forward(chain, head[:3], head[3:], [u[j, :] for j in range(3)], ca.cos, ca.sin)
        return ca.vertcat(*values), ca.vertcat(ay, az, at)

    if limits.torque is not None:
        torque = TORQUE_MARGIN * limits.torque[index]

        def torques(x: Any, u: Any, p: Any) -> Any:
            rows = chain_torques(chain, [x[j, :-1] for j in range(3)], [x[3 + j, :-1] for j in range(3)],
                                 [u[j, :] for j in range(3)], ca.cos, ca.sin)
            return ca.vertcat(*[tau / float(limit) for tau, limit in zip(rows, torque, strict=True)])

        constraints.append(Constraint(f"{chain.robot}'s torque limits", ("chain_torques", chain.robot,
                                      tuple(torque)), torques, -1.0, 1.0))
    if chain.base_line is not None:
        def clearance(x: Any, u: Any, p: Any) -> Any:
            task, _ = to_task(x, u)
            return flange_clearance(chain, task[:, 1:], ca.cos, ca.sin)

        constraints.append(Constraint(f"{chain.robot} clear of its shoulder singularity",
                                      ("chain_clearance", chain.robot, tuple(chain.flange), chain.base_line,
                                       chain.base_side), clearance, SINGULARITY_CLEARANCE, math.inf))
    key = ("planar_chain", chain.robot, tuple(chain.shoulder), chain.upper, chain.fore, tuple(chain.wrist),
           chain.elbow, tuple(chain.home), tuple(chain.axis_sign), bounds)
    return JointSpace(f"{chain.robot}'s joints {', '.join(chain.joints)}", key, 3, to_task, tuple(constraints),
                      bounds, IPOPT_OPTIONS)


def arm_form(robot: str | Robot | None, dt: float) -> ArmForm | None:
    """The robot's joint limits as the pancake polish's arm form (:class:`~seqmotion.core.polish.ArmForm`): the
    polish runs on the chain's joints (:func:`joint_space`); ``None`` where the robot has no planar chain in its
    placement or no known rated speeds: such a motion is only judged (:func:`~seqmotion.sim.executable
    .check_executable`), never promised."""
    standard = resolve_robot(robot)
    chain = planar_chain(standard)
    if standard is None or chain is None or standard.limits.velocity is None:
        return None
    limits = standard.limits
    lowest = TABLE_TOP + TABLE_CLEARANCE + TABLE_MARGIN - float(PANCAKE_ORIGIN[2])  # task z [m]
    above_table = Constraint("the spatula above the table", ("above_table", lowest),
                             lambda x, u, p: x[1, 1:], lowest, math.inf)
    return ArmForm(limits.robot, (above_table,), joint_space(chain, limits),
                   lambda states: chain_joints(chain, states), lambda j, a: chain_task(chain, j, a), JOINT_HOLD)


__all__ = ["ELBOW_MARGIN", "JOINT_HOLD", "PARALLEL_TOLERANCE", "SINGULARITY_CLEARANCE", "SPEED_MARGIN",
           "TORQUE_MARGIN", "PlanarChain", "arm_form", "chain_joint_speeds", "chain_joints", "chain_task",
           "chain_torques", "flange_clearance", "joint_space", "link_angles", "planar_chain"]
