"""A whole-arm optimal control peer for pancake turning on the UR5e: CasADi/IPOPT on the joint trajectory.

The question it answers: how well does the textbook approach do — a roboticist's whole-arm optimal control
problem solved from scratch for each sketch — at making "a pancake-turning motion a UR5e can execute"? It
uses nothing learned and nothing of seqmotion's polish; from seqmotion it takes the task's definitions
(the friction cone and its margin, the task plane, the sketches), the compiled MuJoCo scene and the arm's
published limits. Run from the repository root::

    MUJOCO_GL=egl python benchmarks/peers/arm_ocp.py --n 20 --seed 0     # -> benchmarks/results_arm_ocp_peer.json

**Kinematics.** The tool site's forward kinematics is built symbolically (CasADi SX) from the compiled
scene's kinematic tree at run time — ``body_pos``/``body_quat`` of every body from the world to the site's
body, ``jnt_axis``/``jnt_pos``/``qpos0`` of their joints, then ``site_pos``/``site_quat`` — following
MuJoCo's own ``mj_kinematics`` step by step, so nothing of the arm's placement is written here (another
engineer may move the UR5e in the scene; this follows). :func:`check_fk` compares it with MuJoCo's
``site_xpos``/``site_xmat`` at random postures (max error ~1e-15; the run stops if it exceeds 1e-9).

**Problem** (per sketch, per duration ``T``; ``N = T / h`` intervals of ``h`` = 10 ms):

* decision variables: joint positions ``q_k`` and speeds ``q̇_k`` at the N + 1 knots, and the joint
  accelerations ``q̈_k`` held constant over each interval (a double integrator per joint:
  ``q_{k+1} = q_k + h q̇_k + h²/2 q̈_k``, ``q̇_{k+1} = q̇_k + h q̈_k`` as equality constraints). The joint
  trajectory is thus piecewise quadratic, and sampling it at 1 ms is exact (no interpolation choice);
* cost: smoothness, ``(1/T) Σ_k |q̈_k / 30 rad/s²|² h`` (the integral of the squared joint accelerations,
  normalised so that it is ≈ 1 for a motion at 30 rad/s²: unnormalised, IPOPT needed 2–3× the iterations on
  the README's sketch);
* start: ``q_0`` = the posture that puts the site at the sketch's first state (``solve_ik`` from the
  robot's ``home``), at rest (``q̇_0 = 0``);
* end: the site at the sketch's end ``(y, z, θ)`` (θ as ``sin(θ − θ_end) = 0`` with
  ``cos(θ − θ_end) ≥ 0``: one equation for one degree of freedom), at rest (``q̇_N = 0``);
* task plane, at every knot: site ``x`` = the pancake origin's x (0.5 m), and the tool's axis along world
  +x (the (y, z) entries of the site frame's third column are 0), so the attitude is a pure roll
  ``Rx(θ)·Ry(π/2)`` and ``cos θ``, ``sin θ`` are the site frame's entries ``R[1,1]``, ``R[2,1]``;
* friction cone with the task's margin (μ = 1, 4 m/s², ``POLISH_NORMAL_FLOOR``): with the site's
  acceleration ``a = J(q) q̈ + J̇(q, q̇) q̇`` (y, z) and ``f = g − a``, ``μ n ∓ t ≥ margin`` — at *both ends*
  of every interval (at ``(q_k, q̇_k)`` and at ``(q_{k+1}, q̇_{k+1})``, each with that interval's ``q̈_k``),
  i.e. for the inputs ``u[0..K−2]`` as in the task; between the ends it is re-checked at 1 ms afterwards;
* joint ranges (the model file's) as bounds on ``q_k``; rated speeds (Universal Robots' 180°/s) as bounds
  on ``q̇_k`` — exact everywhere, ``q̇`` being piecewise linear. The UR5e has no published joint
  accelerations (``robot.limits.acceleration`` is unknown), so none is imposed;
* the table: the site's world height ≥ the table's top plus the blade's reach below the site
  (:func:`lowest_site_height`, read from the scene's ``table`` and ``blade`` geoms: −0.087 m, i.e. 0.437 m
  below the pancake's origin), at every knot. Without it the solutions that exist swing the blade in a loop
  0.6–0.8 m below the origin, through the table (the brief did not list it; a motion through the table is
  not one the arm can execute). Collisions of the arm's links are not modelled.

The derivatives IPOPT uses are exact (CasADi's algorithmic differentiation), but assembled per interval
(:func:`_assemble`): the Jacobian and Hessian of one interval's constraints are derived once and mapped over
the N intervals. That builds 15–30× faster than CasADi's derivative of the whole expanded NLP (0.2 s instead
of 3–8 s for N = 150) at ~15 % more time per IPOPT iteration; :func:`check_derivatives` compares the two at
a random point before every run (differences ~1e-14).

**Durations and continuation.** The sketches are 0.3–0.8 s; the durations tried, in order, are the
sketch's own, then 1.0, 1.5 and 2.0 s (those longer than it; rounded up to the 10 ms grid). The first whose
rated problem converges *and* passes the 1 ms re-check is the result. Each try starts from the sketch
stretched to ``T`` and mapped through IK (``solve_ik`` knot by knot, each seeded by the last), and solves a
continuation in the speed limits: 4×, 2×, 1.5×, 1.25×, then 1× rated (the problem itself), each stage from the
last one's solution (primal warm start); a stage that does not converge ends the try. Solved cold at 1×
from the IK guess instead (the first two sketches, before the table bound was added), IPOPT found the one
rated solution the continuation found, at 2.0 s instead of 1.5 s, and hit its caps on most other tries; the
continuation also tells how far from the rated speeds a failed sketch is. Each try has 60 s in all (IPOPT's
CPU and wall-time caps are what is left of it); a stage cut off counts as not converged. IPOPT: MUMPS, exact
Hessian, ``tol`` 1e-6 (``Solved_To_Acceptable_Level`` at ``acceptable_tol`` 1e-4 counts as converged), at
most 1000 iterations per stage. Each row records, beside success, the smallest speed scale the continuation
solved at any duration (``best_speed_scale``: how far from the arm's rated speeds a turn was found) and that
solution's joint speed peaks.

**Re-check** (:func:`check_solution`, with MuJoCo, independent of the symbolic model): the joint
trajectory sampled at 1 ms (``DT``), the site's pose and velocity from ``mj_kinematics`` and
``mj_jacSite``, the planar states ``[y, z, θ, v_y, v_z, v_θ]``, their accelerations as seqmotion scores
any motion (``implied_accel``: forward differences of the velocities), then the cone (``μ n ∓ t ≥ 0``,
i.e. seqmotion's ``F_c = 0``: the pancake stays on; whether the 4 m/s² margin also held at every 1 ms
sample is reported), rated speeds, ranges, the task plane (≤ 1 mm, ≤ 0.01 rad off it), the end pose
(≤ 1 mm, ≤ 0.01 rad) and the table (site height ≥ the bound − 1 mm). Success = IPOPT converged at 1× rated
and every one of these holds.

**Sketches** (:func:`turn_sketches`): ``seqmotion.tasks.pancake.data.straight`` from rest at the origin
``(0, 0, 0)`` to ``(y_end, z_end, θ_end)`` on its S-curve, with ``θ_end ~ U[2, 3]`` rad,
``y_end, z_end ~ U[−0.2, 0.2]`` m and ``K ~ U{301..801}`` samples (0.3–0.8 s at 1 ms), drawn in that
order per sketch from ``numpy.random.default_rng(seed)``.

What was tried and dropped: IPOPT's dual warm start between continuation stages (``warm_start_init_point``
with the last stage's multipliers: faster intermediate stages, but the final 1× stage failed where the
primal warm start converged); an elastic form of the speed limits (slacks with an L1 penalty, ρ = 10 and
1000: IPOPT settled at 2.1–2.4× rated, a local minimum of the violation); a warm start from the planar
(task-space) version of the problem (its solutions roll at 9–12 rad/s, which the arm cannot; the arm OCP
from them failed or ran out of time).

Crocoddyl was not tried: ``pip install crocoddyl==3.2.0 pin==3.9.0`` cannot resolve in seqmotion's venv
(pin 3.9.0 needs cmeel-boost 1.89.0, which requires ``numpy<2.4``; the venv has numpy 2.4.6, and
downgrading the shared venv's numpy is not an option).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import casadi as ca  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from seqmotion.physics.integrator import DT, implied_accel  # noqa: E402
from seqmotion.sim.control import solve_ik  # noqa: E402
from seqmotion.sim.kinematics import planar_reference  # noqa: E402
from seqmotion.sim.robot_models import get_robot  # noqa: E402
from seqmotion.sim.scene import PANCAKE_ORIGIN, get_scene  # noqa: E402
from seqmotion.tasks.pancake import POLISH_NORMAL_FLOOR  # noqa: E402
from seqmotion.tasks.pancake.data import straight  # noqa: E402
from seqmotion.tasks.pancake.physics import GRAVITY, MU, violation  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_OUT = ROOT / "benchmarks" / "results_arm_ocp_peer.json"

KNOT_DT = 0.01
"""Knot spacing h [s]: the cone and the task plane are imposed on these knots, every 10th 1 ms sample."""
MARGIN = POLISH_NORMAL_FLOOR
"""The cone's margin [m/s²] (``μ n ∓ t ≥ MARGIN``): the task's exact polish presses the pancake on with it."""
DURATION_GRID = (1.0, 1.5, 2.0)
"""Durations [s] tried in order after the sketch's own: those of this grid longer than it."""
ACC_REF = 30.0
"""Joint acceleration [rad/s²] the cost is measured in: ``(1/T) Σ |q̈_k / ACC_REF|² h`` (≈ 1 for a motion at it)."""
MAX_ITER = 1000
"""IPOPT's iteration cap per try (converging tries took 50–250)."""
MAX_SECONDS = 60.0
"""Time allowed per try (one duration, all its continuation stages) [s]; IPOPT is capped at what is left."""
SPEED_CONTINUATION = (4.0, 2.0, 1.5, 1.25, 1.0)
"""The speed bounds of a try's stages, × rated: each stage starts from the last one's solution; the last is the
problem itself. A stage that does not converge ends the try."""
PLANE_TOL = (1e-3, 1e-2)
"""Largest distance [m] and tilt [rad] off the task plane the 1 ms re-check accepts."""
END_TOL = (1e-3, 1e-2)
"""Largest end-position [m] and end-attitude [rad] error the 1 ms re-check accepts."""
FK_TOL = 1e-9
"""Largest difference between the symbolic FK and MuJoCo's the run accepts."""

THETA_END = (2.0, 3.0)
END_YZ = 0.2
LENGTH = (301, 801)


# ----------------------------------------------------------------------------------------------- sketches


def turn_sketches(n: int, seed: int) -> list[np.ndarray]:
    """The benchmark's ``n`` turn sketches, ``(K, 6)`` planar states at 1 ms each (see the module docstring).

    Per sketch, in this order from ``numpy.random.default_rng(seed)``: ``θ_end ~ U[2, 3]`` rad,
    ``y_end ~ U[−0.2, 0.2]`` m, ``z_end ~ U[−0.2, 0.2]`` m, ``K ~ U{301, …, 801}`` samples (0.3–0.8 s);
    the motion is ``seqmotion.tasks.pancake.data.straight((y_end, z_end, θ_end), K)``: rest to rest from the
    origin on an S-curve.
    """
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        theta = rng.uniform(*THETA_END)
        y, z = rng.uniform(-END_YZ, END_YZ, size=2)
        k = int(rng.integers(LENGTH[0], LENGTH[1] + 1))
        out.append(straight((y, z, theta), k))
    return out


# ------------------------------------------------------------------------------------- symbolic kinematics


def _quat_matrix(quat: np.ndarray) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=np.float64))
    return mat.reshape(3, 3)


def _axis_rotation(axis: np.ndarray, angle: ca.SX) -> ca.SX:
    """Rodrigues: the rotation by ``angle`` about the unit ``axis`` (numeric), symbolic in the angle."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return ca.DM(np.eye(3)) + ca.sin(angle) * ca.DM(k) + (1 - ca.cos(angle)) * ca.DM(k @ k)


def site_chain(model, site: int) -> list[int]:
    """Body ids from the world's first child down to the site's body."""
    chain, body = [], int(model.site_bodyid[site])
    while body != 0:
        chain.append(body)
        body = int(model.body_parentid[body])
    return chain[::-1]


def symbolic_site_fk(scene) -> ca.Function:
    """``fk(q) -> (pos (3,), R (3, 3))`` of the scene's tool site, ``q`` the arm joints in ``scene.arm_qpos``
    order, built from the compiled model's tree exactly as ``mj_kinematics`` composes it.

    Per body: ``xpos = xpos_parent + R_parent body_pos``, ``R = R_parent quat(body_quat)``; per hinge joint of
    the body: the anchor ``xpos + R jnt_pos`` stays put while ``R ← R · rot(jnt_axis, q − qpos0)`` (slides
    move ``xpos`` along ``R jnt_axis``). A joint of the chain that is not an arm joint (or a free/ball joint)
    is refused: the site's pose must depend on the arm alone.
    """
    model = scene.model
    qpos_index = {int(a): i for i, a in enumerate(scene.arm_qpos)}
    q = ca.SX.sym("q", len(scene.arm_qpos))
    pos, rot = ca.DM.zeros(3), ca.DM(np.eye(3))
    for body in site_chain(model, scene.site):
        pos = pos + rot @ ca.DM(model.body_pos[body])
        rot = rot @ ca.DM(_quat_matrix(model.body_quat[body]))
        for j in range(model.body_jntadr[body], model.body_jntadr[body] + model.body_jntnum[body]):
            kind, adr = int(model.jnt_type[j]), int(model.jnt_qposadr[j])
            if adr not in qpos_index:
                raise ValueError(f"joint {j} on the site's chain is not an arm joint")
            angle = q[qpos_index[adr]] - float(model.qpos0[adr])
            if kind == mujoco.mjtJoint.mjJNT_HINGE:
                anchor = pos + rot @ ca.DM(model.jnt_pos[j])
                rot = rot @ _axis_rotation(model.jnt_axis[j], angle)
                pos = anchor - rot @ ca.DM(model.jnt_pos[j])
            elif kind == mujoco.mjtJoint.mjJNT_SLIDE:
                pos = pos + rot @ ca.DM(model.jnt_axis[j]) * angle
            else:
                raise ValueError(f"joint {j} on the site's chain is neither a hinge nor a slide")
    site_pos = pos + rot @ ca.DM(model.site_pos[scene.site])
    site_rot = rot @ ca.DM(_quat_matrix(model.site_quat[scene.site]))
    return ca.Function("site_fk", [q], [site_pos, site_rot], ["q"], ["pos", "rot"])


def check_fk(scene, fk: ca.Function, samples: int = 200, seed: int = 0) -> float:
    """Largest difference of ``fk`` from MuJoCo's ``site_xpos``/``site_xmat`` at random postures
    (uniform in the joint ranges, ±π where a joint has none)."""
    model = scene.model
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    limited = model.jnt_limited[[_joint_of(model, a) for a in scene.arm_qpos]].astype(bool)
    ranges = model.jnt_range[[_joint_of(model, a) for a in scene.arm_qpos]]
    low = np.where(limited, ranges[:, 0], -math.pi)
    high = np.where(limited, ranges[:, 1], math.pi)
    worst = 0.0
    for _ in range(samples):
        q = rng.uniform(low, high)
        data.qpos[scene.arm_qpos] = q
        mujoco.mj_kinematics(model, data)
        pos, rot = fk(q)
        worst = max(worst, float(np.abs(np.asarray(pos).ravel() - data.site_xpos[scene.site]).max()),
                    float(np.abs(np.asarray(rot) - data.site_xmat[scene.site].reshape(3, 3)).max()))
    return worst


def _joint_of(model, qpos_adr: int) -> int:
    return int(np.flatnonzero(model.jnt_qposadr == qpos_adr)[0])


def site_kinematics(fk: ca.Function) -> ca.Function:
    """``kin(q, q̇, q̈) -> (x, y, z, R[1,2], R[2,2], cos θ = R[1,1], sin θ = R[2,1], a_y, a_z)`` of the site:
    ``a = J q̈ + J̇ q̇`` (the second time derivative of ``pos(q(t))``)."""
    n = fk.size1_in(0)
    q, qd, qdd = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("qdd", n)
    pos, rot = fk(q)
    vel = ca.jtimes(pos, q, qd)
    acc = ca.jtimes(vel, q, qd) + ca.jtimes(pos, q, qdd)
    out = ca.vertcat(pos[0], pos[1], pos[2], rot[1, 2], rot[2, 2], rot[1, 1], rot[2, 1], acc[1], acc[2])
    return ca.Function("site_kin", [q, qd, qdd], [out])


# ------------------------------------------------------------------------------------------------ the OCP


def _planar_pose(state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The site's target position and quaternion for one planar state (the task's own mapping)."""
    ref = planar_reference(np.asarray(state, dtype=np.float64)[None], decel_time=0.0)
    return ref.pos[0], ref.quat[0]


def initial_guess(scene, robot, sketch: np.ndarray, n: int, h: float, q0: np.ndarray) -> np.ndarray:
    """Joint knots ``(n + 1, dof)``: the sketch stretched to ``n h`` seconds, through IK knot by knot."""
    k = sketch.shape[0]
    s = np.linspace(0.0, k - 1.0, n + 1)
    pts = np.stack([np.interp(s, np.arange(k), sketch[:, i]) for i in range(3)], -1)
    qs, q = [q0], q0
    for p in pts[1:]:
        pos, quat = _planar_pose(np.concatenate([p, np.zeros(3)]))
        try:
            q = solve_ik(scene, pos, quat, seed=q)
        except ValueError:  # out of reach: keep the last posture, the solver moves it
            pass
        qs.append(q)
    return np.array(qs)


@dataclass
class Problem:
    """One OCP at a fixed duration, built once; speed limits are bounds, so a continuation re-solves it."""

    nlp: dict
    options: dict
    n: int
    h: float
    dof: int
    rated: np.ndarray
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    x_init: np.ndarray
    speed_rows: np.ndarray
    cone_rows: np.ndarray
    build_s: float

    def bounds(self, speed_scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``lbx``, ``ubx``, ``lbg``, ``ubg`` with the speed bounds (``speed_rows`` of x) at ``speed_scale`` × rated
        (the end speeds stay 0)."""
        lbx, ubx = self.lbx.copy(), self.ubx.copy()
        lbx[self.speed_rows] *= speed_scale
        ubx[self.speed_rows] *= speed_scale
        return lbx, ubx, self.lbg, self.ubg

    def solver(self, max_seconds: float = MAX_SECONDS, warm: bool = False) -> ca.Function:
        """IPOPT on this NLP (its derivative functions are built already: this takes milliseconds), capped at
        ``max_seconds`` of CPU and wall time; ``warm``: started from a previous solution and its multipliers."""
        opts = dict(self.options)
        opts.update({"ipopt.max_cpu_time": max_seconds, "ipopt.max_wall_time": max_seconds})
        if warm:
            opts.update(WARM_OPTIONS)
        return ca.nlpsol("arm_ocp", "ipopt", self.nlp, opts)

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        nq = self.dof * (self.n + 1)
        return (x[:nq].reshape(self.n + 1, self.dof), x[nq:2 * nq].reshape(self.n + 1, self.dof),
                x[2 * nq:2 * nq + self.dof * self.n].reshape(self.n, self.dof))


def _cone(rows: ca.SX) -> ca.SX:
    """``μ n − t`` and ``μ n + t`` from a ``site_kin`` output (cos θ, sin θ and a_y, a_z in rows 5–8)."""
    fy, fz = -rows[7], -GRAVITY - rows[8]
    c, s = rows[5], rows[6]
    normal, tangent = fy * s - fz * c, fy * c + fz * s
    return ca.vertcat(MU * normal - tangent, MU * normal + tangent)


def _interval_function(kin: ca.Function, dof: int, h: float, origin: np.ndarray) -> ca.Function:
    """The constraints of one interval k, of ``z = [q_k, q̇_k, q_{k+1}, q̇_{k+1}, q̈_k]``: the double integrator
    (2 dof), the task plane at knot k (3), the cone at both ends of the interval with ``q̈_k`` (2 + 2) and the
    site's height at knot k (1, ≥ :func:`lowest_site_height`)."""
    z = ca.SX.sym("z", 5 * dof)
    qk, qdk, qk1, qdk1, a = (z[i * dof:(i + 1) * dof] for i in range(5))
    left, right = kin(qk, qdk, a), kin(qk1, qdk1, a)
    out = ca.vertcat(qk1 - qk - h * qdk - 0.5 * h**2 * a, qdk1 - qdk - h * a,
                     left[0] - origin[0], left[3], left[4], _cone(left), _cone(right), left[2])
    return ca.Function("interval", [z], [out])


def _terminal_function(kin: ca.Function, dof: int, origin: np.ndarray, end: np.ndarray) -> ca.Function:
    """The constraints on the last knot, of ``z = [q_N, q̇_N]``: the task plane (3), the end position (2),
    ``sin(θ − θ_end)`` (1) and ``cos(θ − θ_end)`` (1, ≥ 0)."""
    z = ca.SX.sym("z", 2 * dof)
    last = kin(z[:dof], z[dof:], ca.DM.zeros(dof))
    ce, se = math.cos(end[2]), math.sin(end[2])
    out = ca.vertcat(last[0] - origin[0], last[3], last[4], last[1] - (origin[1] + end[0]),
                     last[2] - (origin[2] + end[1]), last[6] * ce - last[5] * se, last[5] * ce + last[6] * se)
    return ca.Function("terminal", [z], [out])


def lowest_site_height(scene) -> float:
    """The lowest world z the tool site may take [m]: the table's top (geom ``"table"``, a world box) plus the
    blade's reach below the site (geom ``"blade"``: its bounding radius plus the site's distance from its centre),
    so that no part of the blade can touch the table whatever its roll. Read from the compiled scene."""
    model = scene.model
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    table = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table")
    blade = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "blade")
    if table < 0 or blade < 0:
        return -math.inf
    top = float(data.geom_xpos[table][2] + np.abs(data.geom_xmat[table].reshape(3, 3)[2]) @ model.geom_size[table])
    offset = np.linalg.norm(data.geom_xpos[blade] - data.site_xpos[scene.site])
    reach = float(np.linalg.norm(model.geom_size[blade]) + offset)
    return top + reach


def _assemble(x: ca.MX, lam_g: ca.MX, stages: list[tuple[ca.Function, np.ndarray]]):
    """``g``, its Jacobian and the upper triangle of ``Σ λ_g ∇²g`` from per-stage functions.

    Each stage is a function of a few entries of ``x`` (``idx``: (inputs, instances) indices into x), mapped
    over its instances; its derivatives are taken once, symbolically (SX), on the small function, mapped
    likewise and scattered into the large sparse matrices by index (an MX graph of a few nodes). That
    builds in a fraction of the time CasADi's derivative of the whole expanded NLP takes and evaluates as
    fast; the numbers are the same (:func:`check_derivatives`).
    """
    nx, ng = x.shape[0], lam_g.shape[0]
    g_parts, j_rows, j_cols, j_vals, h_rows, h_cols, h_vals = [], [], [], [], [], [], []
    base = 0
    for fn, idx in stages:
        n_in, m = idx.shape
        n_out = fn.size1_out(0)
        z = ca.reshape(x[idx.ravel(order="F").tolist()], n_in, m)
        lam = ca.reshape(lam_g[base:base + n_out * m], n_out, m)
        zs, ls = ca.SX.sym("z", n_in), ca.SX.sym("l", n_out)
        out = fn(zs)
        jac = ca.Function("stage_jac", [zs], [ca.jacobian(out, zs)])
        hess = ca.Function("stage_hess", [zs, ls], [ca.hessian(ca.dot(ls, out), zs)[0]])
        g_parts.append(ca.vec(fn.map(m)(z)))
        for f, args, kind in ((jac, [z], "j"), (hess, [z, lam], "h")):
            r, c = f.sparsity_out(0).get_triplet()
            r, c = np.asarray(r, dtype=np.int64), np.asarray(c, dtype=np.int64)
            vals = f.map(m)(*args).nz[:]
            inst = np.repeat(np.arange(m), len(r))
            rr, cc = np.tile(r, m), np.tile(c, m)
            if kind == "j":
                j_rows.append(base + inst * n_out + rr)
                j_cols.append(idx[cc, inst])
                j_vals.append(vals)
            else:
                h_rows.append(idx[rr, inst])
                h_cols.append(idx[cc, inst])
                h_vals.append(vals)
        base += n_out * m

    def sparse(rows, cols, vals, shape, upper=False):
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        keep = rows <= cols if upper else np.ones(rows.shape, dtype=bool)
        key = cols * shape[0] + rows  # column-major, as CasADi stores nonzeros
        uniq, where = np.unique(key[keep], return_inverse=True)
        entries = np.flatnonzero(keep)
        gather = ca.DM(ca.Sparsity.triplet(len(uniq), len(key), where.tolist(), entries.tolist()),
                       np.ones(len(entries)))
        sp = ca.Sparsity.triplet(shape[0], shape[1], (uniq % shape[0]).tolist(), (uniq // shape[0]).tolist())
        return ca.MX(sp, ca.mtimes(gather, ca.vertcat(*vals)))

    return (ca.vertcat(*g_parts), sparse(j_rows, j_cols, j_vals, (ng, nx)),
            sparse(h_rows, h_cols, h_vals, (nx, nx), upper=True))


def build_problem(scene, robot, kin: ca.Function, sketch: np.ndarray, duration: float, q0: np.ndarray,
                  h: float = KNOT_DT, structured: bool = True) -> Problem:
    """The OCP of the module docstring at ``duration`` (rounded up to the knot grid), with its IK initial guess.

    ``structured``: hand IPOPT the Jacobian and Hessian assembled per interval (:func:`_assemble`); False lets
    CasADi differentiate the whole NLP (the same derivatives, several times slower to build).
    """
    start = time.perf_counter()
    n = max(2, math.ceil(round(duration / h, 9)))
    dof = len(scene.arm_qpos)
    limits = robot.limits
    rated = np.asarray(limits.velocity, dtype=np.float64)
    qrange = np.asarray(limits.position, dtype=np.float64)
    end = np.asarray(sketch[-1, :3], dtype=np.float64)
    origin = np.asarray(PANCAKE_ORIGIN, dtype=np.float64)

    nq = dof * (n + 1)
    nx = 2 * nq + dof * n
    ix_q = np.arange(nq).reshape(n + 1, dof)  # x = [q_0..q_N, q̇_0..q̇_N, q̈_0..q̈_{N-1}], knot-major
    ix_qd = nq + ix_q
    ix_qdd = 2 * nq + np.arange(dof * n).reshape(n, dof)
    interval_idx = np.concatenate([ix_q[:-1], ix_qd[:-1], ix_q[1:], ix_qd[1:], ix_qdd], axis=1).T  # (5 dof, n)
    terminal_idx = np.concatenate([ix_q[-1], ix_qd[-1]])[:, None]  # (2 dof, 1)
    stages = [(_interval_function(kin, dof, h, origin), interval_idx),
              (_terminal_function(kin, dof, origin, end), terminal_idx)]
    n_eq = 2 * dof + 3
    z_min = lowest_site_height(scene)
    lbg = np.concatenate([np.tile(np.r_[np.zeros(n_eq), np.full(4, MARGIN), z_min], n), np.zeros(7)])
    ubg = np.concatenate([np.tile(np.r_[np.zeros(n_eq), np.full(4, np.inf), np.inf], n), np.zeros(6), [np.inf]])
    cone_rows = (np.arange(n)[:, None] * (n_eq + 5) + n_eq + np.arange(4)[None, :]).ravel()

    x = ca.MX.sym("x", nx)
    qdd = x[2 * nq:]
    weight = h / (n * h * ACC_REF**2)
    cost = weight * ca.sumsqr(qdd)
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.linear_solver": "mumps",
            "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4, "ipopt.acceptable_iter": 10,
            "ipopt.max_iter": MAX_ITER}
    opts.update(IPOPT_EXTRA)
    if structured:
        lam_g, lam_f, p = ca.MX.sym("lam_g", len(lbg)), ca.MX.sym("lam_f"), ca.MX.sym("p", 0)
        g, jac, hess_g = _assemble(x, lam_g, stages)
        diag = ca.MX(ca.Sparsity.triplet(nx, nx, ix_qdd.ravel().tolist(), ix_qdd.ravel().tolist()),
                     ca.repmat(2 * weight * lam_f, dof * n, 1))
        opts["jac_g"] = ca.Function("jac_g", [x, p], [g, jac])
        opts["hess_lag"] = ca.Function("hess_lag", [x, p, lam_f, lam_g], [hess_g + diag])
    else:
        g = ca.vertcat(*[ca.vec(fn.map(idx.shape[1])(ca.reshape(x[idx.ravel(order="F").tolist()], *idx.shape)))
                         for fn, idx in stages])
    nlp = {"x": x, "f": cost, "g": g}

    # Bounds: ranges, rated speeds, start posture at rest, end at rest.
    qlo = np.tile(qrange[:, 0], (n + 1, 1))
    qhi = np.tile(qrange[:, 1], (n + 1, 1))
    qlo[0] = qhi[0] = q0
    vhi = np.tile(rated, (n + 1, 1))
    vhi[[0, n]] = 0.0
    lbx = np.concatenate([qlo.ravel(), -vhi.ravel(), np.full(dof * n, -np.inf)])
    ubx = np.concatenate([qhi.ravel(), vhi.ravel(), np.full(dof * n, np.inf)])

    # Initial guess: the stretched sketch through IK, speeds and accelerations consistent with it.
    q_init = np.clip(initial_guess(scene, robot, sketch, n, h, q0), qrange[:, 0], qrange[:, 1])
    qd_init = np.gradient(q_init, h, axis=0)
    qd_init[[0, -1]] = 0.0
    qdd_init = np.diff(qd_init, axis=0) / h
    x_init = np.concatenate([q_init.ravel(), qd_init.ravel(), qdd_init.ravel()])
    return Problem(nlp, opts, n, h, dof, rated, lbx, ubx, lbg, ubg, x_init, np.arange(nq, 2 * nq), cone_rows,
                   time.perf_counter() - start)


IPOPT_EXTRA: dict = {}
"""More IPOPT options (experiments)."""


def solve_problem(problem: Problem, speed_scale: float = 1.0, warm: dict | None = None,
                  max_seconds: float = MAX_SECONDS) -> dict:
    """Solve ``problem`` with the speed limits at ``speed_scale`` × rated, from its IK guess, or from ``warm``
    (a previous stage's result: its ``x`` and multipliers)."""
    start = time.perf_counter()
    lbx, ubx, lbg, ubg = problem.bounds(speed_scale)
    if warm is None:
        solver = problem.solver(max_seconds)
        sol = solver(x0=np.clip(problem.x_init, lbx, ubx), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    else:
        solver = problem.solver(max_seconds, warm=WARM_DUALS)
        args = {"lam_x0": warm["lam_x"], "lam_g0": warm["lam_g"]} if WARM_DUALS else {}
        sol = solver(x0=np.clip(warm["x"], lbx, ubx), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, **args)
    stats = solver.stats()
    status = str(stats["return_status"])
    xs = np.asarray(sol["x"]).ravel()
    q, qd, qdd = problem.unpack(xs)
    cone = np.asarray(sol["g"]).ravel()[problem.cone_rows]
    return {
        "speed_scale": speed_scale, "duration_s": problem.n * problem.h, "intervals": problem.n,
        "status": status, "converged": status in CONVERGED, "iterations": int(stats["iter_count"]),
        "cost": float(sol["f"]), "seconds": time.perf_counter() - start,
        "min_cone_margin_knots": float(cone.min()), "x": xs, "q": q, "qd": qd, "qdd": qdd, "h": problem.h,
        "lam_x": np.asarray(sol["lam_x"]).ravel(), "lam_g": np.asarray(sol["lam_g"]).ravel(),
    }


WARM_DUALS = False
WARM_OPTIONS = {"ipopt.warm_start_init_point": "yes", "ipopt.mu_init": 1e-4, "ipopt.warm_start_bound_push": 1e-6,
                "ipopt.warm_start_mult_bound_push": 1e-6, "ipopt.warm_start_slack_bound_push": 1e-6}
"""A continuation stage starts from the last one's solution and multipliers, with a small barrier."""


CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


def check_derivatives(scene, robot, duration: float = 0.1, seed: int = 0) -> float:
    """Largest difference between the structured Jacobian and Hessian (:func:`_assemble`) and CasADi's own
    derivatives of the same NLP, at a random point with random multipliers (a short problem: 10 intervals)."""
    kin = site_kinematics(symbolic_site_fk(scene))
    sketch = straight((0.1, -0.1, 2.5), round(duration / DT) + 1)
    pos, quat = _planar_pose(sketch[0])
    q0 = solve_ik(scene, pos, quat, seed=robot.home)
    mine = build_problem(scene, robot, kin, sketch, duration, q0, structured=True)
    auto = build_problem(scene, robot, kin, sketch, duration, q0, structured=False)
    rng = np.random.default_rng(seed)
    x, lam_g = rng.normal(size=mine.x_init.shape), rng.normal(size=mine.lbg.shape)
    worst = 0.0
    for name, args in (("nlp_jac_g", [x, []]), ("nlp_hess_l", [x, [], 0.7, lam_g])):
        a = mine.solver().get_function(name)(*args)
        b = auto.solver().get_function(name)(*args)
        a, b = (a[-1] if isinstance(a, (list, tuple)) else a), (b[-1] if isinstance(b, (list, tuple)) else b)
        a, b = np.asarray(ca.densify(a)), np.asarray(ca.densify(b))
        if name == "nlp_hess_l":
            a, b = np.triu(a), np.triu(b)
        worst = max(worst, float(np.abs(a - b).max()))
    return worst


def placement(scene) -> dict:
    """Where the arm stands in the compiled scene (for the record): its base body's world pose and the tool
    site's pose at the start posture of a sketch at the origin."""
    model = scene.model
    chain = site_chain(model, scene.site)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    base = chain[0]
    return {"base_body": mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, base),
            "base_pos": data.xpos[base].round(6).tolist(), "base_quat": data.xquat[base].round(6).tolist()}


# ----------------------------------------------------------------------------------------------- re-check


def sample_joints(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, h: float, dt: float = DT):
    """The piecewise-quadratic joint trajectory at ``dt``: ``(K, dof)`` positions and speeds, ``K = n h / dt + 1``."""
    per = round(h / dt)
    if abs(per * dt - h) > 1e-12:
        raise ValueError(f"knot spacing {h} is not a multiple of {dt}")
    n = qdd.shape[0]
    tau = (np.arange(per) * dt)[None, :, None]
    pos = q[:-1, None] + tau * qd[:-1, None] + 0.5 * tau**2 * qdd[:, None]
    vel = qd[:-1, None] + tau * qdd[:, None]
    pos = np.concatenate([pos.reshape(n * per, -1), q[-1:]])
    vel = np.concatenate([vel.reshape(n * per, -1), qd[-1:]])
    return pos, vel


def check_solution(scene, robot, sol: dict, sketch: np.ndarray) -> dict:
    """The 1 ms re-check with MuJoCo (see the module docstring)."""
    model = scene.model
    data = mujoco.MjData(model)
    pos_q, vel_q = sample_joints(sol["q"], sol["qd"], sol["qdd"], sol["h"])
    k = pos_q.shape[0]
    origin = np.asarray(PANCAKE_ORIGIN, dtype=np.float64)
    site = scene.site
    jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    xyz, mats, lin, ang = np.zeros((k, 3)), np.zeros((k, 3, 3)), np.zeros((k, 3)), np.zeros((k, 3))
    for i in range(k):
        data.qpos[scene.arm_qpos] = pos_q[i]
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_jacSite(model, data, jp, jr, site)
        xyz[i], mats[i] = data.site_xpos[site], data.site_xmat[site].reshape(3, 3)
        lin[i], ang[i] = jp[:, scene.arm_dof] @ vel_q[i], jr[:, scene.arm_dof] @ vel_q[i]
    theta = np.unwrap(np.arctan2(mats[:, 2, 1], mats[:, 1, 1]))
    states = np.column_stack([xyz[:, 1] - origin[1], xyz[:, 2] - origin[2], theta, lin[:, 1], lin[:, 2], ang[:, 0]])
    accel = implied_accel(states)
    fy, fz = -accel[:, 0], -GRAVITY - accel[:, 1]
    th = theta[:-1]
    normal, tangent = fy * np.sin(th) - fz * np.cos(th), fy * np.cos(th) + fz * np.sin(th)
    margin = np.minimum(MU * normal - tangent, MU * normal + tangent)
    f_c = violation(states, accel, MU)
    limits = robot.limits
    rated = np.asarray(limits.velocity, dtype=np.float64)
    qrange = np.asarray(limits.position, dtype=np.float64)
    speed_peak = np.abs(vel_q).max(0)
    plane_dist = np.abs(xyz[:, 0] - origin[0]).max()
    plane_tilt = np.arccos(np.clip(mats[:, 0, 2], -1.0, 1.0)).max()
    end = sketch[-1, :3]
    end_pos_err = float(np.hypot(states[-1, 0] - end[0], states[-1, 1] - end[1]))
    end_att_err = float(abs(math.remainder(states[-1, 2] - end[2], 2 * math.pi)))
    checks = {
        "cone": bool(margin.min() >= 0.0 and f_c.max() == 0.0),
        "speed": bool(np.all(speed_peak <= rated * (1 + 1e-6))),
        "range": bool(np.all(pos_q >= qrange[:, 0] - 1e-9) and np.all(pos_q <= qrange[:, 1] + 1e-9)),
        "plane": bool(plane_dist <= PLANE_TOL[0] and plane_tilt <= PLANE_TOL[1]),
        "end": bool(end_pos_err <= END_TOL[0] and end_att_err <= END_TOL[1]),
        "table": bool(xyz[:, 2].min() >= lowest_site_height(scene) - PLANE_TOL[0]),
    }
    return {
        "checks": checks, "ok": all(checks.values()),
        "samples": k,
        "min_cone_margin_1ms": float(margin.min()),
        "margin_held_1ms": bool(margin.min() >= MARGIN - 1e-6),
        "max_violation_rad": float(f_c.max()),
        "joint_speed_peak": speed_peak.tolist(),
        "joint_speed_peak_over_rated": float((speed_peak / rated).max()),
        "joint_accel_peak": np.abs(sol["qdd"]).max(0).tolist(),
        "site_accel_peak": float(np.hypot(accel[:, 0], accel[:, 1]).max()),
        "theta_end_unwrapped": float(theta[-1]),
        "plane_dist_max_m": float(plane_dist), "plane_tilt_max_rad": float(plane_tilt),
        "site_z_min_m": float(xyz[:, 2].min() - origin[2]), "site_yz_extent_m": float(np.hypot(
            xyz[:, 1] - origin[1], xyz[:, 2] - origin[2]).max()),
        "end_pos_err_m": end_pos_err, "end_att_err_rad": end_att_err,
    }


# ----------------------------------------------------------------------------------------------- per sketch


def durations(sketch_duration: float, grid=DURATION_GRID) -> list[float]:
    """The durations tried for a sketch, in order: its own, then every grid duration longer than it."""
    return [sketch_duration] + [t for t in grid if t > sketch_duration + 1e-9]


def plan_turn(sketch: np.ndarray, scene=None, robot=None, grid=DURATION_GRID, h: float = KNOT_DT,
              max_seconds: float = MAX_SECONDS, continuation=SPEED_CONTINUATION, verbose: bool = False) -> dict:
    """Solve the arm OCP for one sketch, trying its durations in order (:func:`durations`).

    Returns a row: success, the duration used, the total wall time (every try: its problem build with the IK
    initial guess, its solve and its 1 ms re-check), each try, and the accepted try's re-check (or, on
    failure, the last try's, of an iterate that is no solution).
    """
    robot = get_robot("ur5e") if robot is None else robot
    scene = get_scene("pancake", robot) if scene is None else scene
    start = time.perf_counter()
    kin = site_kinematics(symbolic_site_fk(scene))
    pos, quat = _planar_pose(sketch[0])
    q0 = solve_ik(scene, pos, quat, seed=robot.home)
    sketch_duration = (sketch.shape[0] - 1) * DT
    tries, accepted, best = [], None, None
    for duration in durations(sketch_duration, grid):
        t0 = time.perf_counter()
        problem = build_problem(scene, robot, kin, sketch, duration, q0, h)
        stages, last = [], None
        for scale in continuation:
            left = max_seconds - (time.perf_counter() - t0)
            if left < 1.0:
                stages.append({"speed_scale": scale, "status": "try_time_spent"})
                break
            sol = solve_problem(problem, scale, last, left)
            stages.append({k: sol[k] for k in ("speed_scale", "status", "iterations", "seconds")})
            if not sol["converged"]:
                break
            last = sol
        row = {"duration_s": problem.n * h, "intervals": problem.n, "build_s": problem.build_s, "stages": stages,
               "speed_scale_reached": None if last is None else last["speed_scale"]}
        if last is not None:
            check = check_solution(scene, robot, last, sketch)
            row.update(check_ok=check["ok"], checks=check["checks"], min_cone_margin_1ms=check["min_cone_margin_1ms"],
                       joint_speed_peak=check["joint_speed_peak"],
                       joint_speed_peak_over_rated=check["joint_speed_peak_over_rated"])
            if best is None or last["speed_scale"] < best[0]["speed_scale"]:
                best = (last, check)
            if last["speed_scale"] == 1.0 and check["ok"]:
                accepted = (last, check)
        row["try_s"] = time.perf_counter() - t0
        tries.append(row)
        if verbose:
            print(f"    T = {problem.n * h:.2f} s: " + ", ".join(
                f"{st['speed_scale']:g}x {st['status']} {st.get('iterations', '')}" for st in stages)
                + f" ({row['try_s']:.1f} s)"
                + ("" if last is None else f"; re-check at {last['speed_scale']:g}x: "
                   f"{[k for k, v in check['checks'].items() if not v] or 'all hold'}"), flush=True)
        if accepted is not None:
            break
    seconds = time.perf_counter() - start
    row = {"end": sketch[-1, :3].tolist(), "sketch_duration_s": sketch_duration, "success": accepted is not None,
           "seconds": seconds, "n_tries": len(tries)}
    if accepted is not None:
        sol, check = accepted
        row.update(duration_s=sol["duration_s"], duration_factor=sol["duration_s"] / sketch_duration,
                   iterations=sol["iterations"], **{k: v for k, v in check.items() if k != "checks"},
                   checks=check["checks"])
    # The least relaxed solution found (the accepted one, or where the continuation stopped): how far the
    # rated speeds are from a motion, and its joint speed peaks.
    if best is not None:
        row.update(best_speed_scale=best[0]["speed_scale"], best_duration_s=best[0]["duration_s"],
                   best_joint_speed_peak=best[1]["joint_speed_peak"])
    row["tries"] = tries
    return row


# ------------------------------------------------------------------------------------------------------ main


def _machine() -> str:
    try:
        from seqmotion.training.provenance import machine_description

        return machine_description()
    except Exception:  # pragma: no cover - provenance is optional here
        return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20, help="number of turn sketches")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robot", default="ur5e")
    parser.add_argument("--knot-dt", type=float, default=KNOT_DT, help="knot spacing [s] (a multiple of 1 ms)")
    parser.add_argument("--max-seconds", type=float, default=MAX_SECONDS,
                        help="time per try (one duration, all its continuation stages) [s]")
    parser.add_argument("--readme", action="store_true", help="also solve the README's straight((0.2, 0, 2.5), 500)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)

    robot = get_robot(args.robot)
    scene = get_scene("pancake", robot)
    fk_error = check_fk(scene, symbolic_site_fk(scene))
    print(f"symbolic FK vs MuJoCo: max error {fk_error:.2e} over 200 random postures", flush=True)
    if not fk_error <= FK_TOL:
        print(f"arm_ocp: error: symbolic FK differs from MuJoCo by {fk_error:.2e} > {FK_TOL:g}", file=sys.stderr)
        return 1
    deriv_error = check_derivatives(scene, robot)
    print(f"structured Jacobian/Hessian vs CasADi's own: max error {deriv_error:.2e}", flush=True)
    if not deriv_error <= 1e-8:
        print(f"arm_ocp: error: structured derivatives differ by {deriv_error:.2e}", file=sys.stderr)
        return 1

    load_before = os.getloadavg()
    sketches = turn_sketches(args.n, args.seed)
    rows = []
    for i, sketch in enumerate(sketches):
        print(f"sketch {i}: end {np.round(sketch[-1, :3], 3).tolist()}, {(sketch.shape[0] - 1) * DT:.3f} s",
              flush=True)
        row = plan_turn(sketch, scene, robot, h=args.knot_dt, max_seconds=args.max_seconds, verbose=True)
        row["index"] = i
        rows.append(row)
        print(f"  -> success {row['success']}, {row['seconds']:.1f} s"
              + (f", T = {row['duration_s']:.2f} s, speed peak/rated {row['joint_speed_peak_over_rated']:.3f}"
                 if row["success"] else ""), flush=True)
    readme = None
    if args.readme:
        readme = plan_turn(straight((0.2, 0.0, 2.5), 500), scene, robot, h=args.knot_dt,
                           max_seconds=args.max_seconds, verbose=True)

    seconds = np.array([r["seconds"] for r in rows])
    ok = [r for r in rows if r["success"]]
    summary = {
        "n": len(rows), "success": len(ok),
        "median_seconds": float(np.median(seconds)) if rows else None,
        "p95_seconds": float(np.percentile(seconds, 95)) if rows else None,
        "max_seconds": float(seconds.max()) if rows else None,
        "median_duration_factor": float(np.median([r["duration_factor"] for r in ok])) if ok else None,
        "median_duration_s": float(np.median([r["duration_s"] for r in ok])) if ok else None,
        "max_joint_speed_peak_over_rated": float(max(r["joint_speed_peak_over_rated"] for r in ok)) if ok else None,
        "min_cone_margin_1ms": float(min(r["min_cone_margin_1ms"] for r in ok)) if ok else None,
        "margin_held_1ms": sum(r["margin_held_1ms"] for r in ok),
        "tries_total": int(sum(len(r["tries"]) for r in rows)),
        # Per sketch, the smallest speed scale (× rated) the continuation solved at any duration: 1 = executable.
        "best_speed_scale_counts": {f"{k:g}": sum(r.get("best_speed_scale") == k for r in rows)
                                    for k in SPEED_CONTINUATION},
        "no_stage_converged": sum("best_speed_scale" not in r for r in rows),
    }
    result = {
        "what": "whole-arm OCP peer (CasADi/IPOPT, from scratch) for pancake turns on the UR5e",
        "command": "python benchmarks/peers/arm_ocp.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "robot": robot.label, "seed": args.seed, "knot_dt_s": args.knot_dt, "margin_m_s2": MARGIN, "mu": MU,
        "duration_grid_s": list(DURATION_GRID), "max_seconds_per_try": args.max_seconds, "max_iter": MAX_ITER,
        "acc_ref": ACC_REF, "derivative_max_error": deriv_error, "placement": placement(scene),
        "rated_speed_rad_s": np.asarray(robot.limits.velocity).tolist(),
        "speed_continuation": list(SPEED_CONTINUATION),
        "fk_max_error": fk_error, "casadi": ca.__version__, "machine": _machine(),
        "load_average_before": [round(v, 2) for v in load_before],
        "load_average_after": [round(v, 2) for v in os.getloadavg()],
        "summary": summary, "rows": rows,
    }
    if readme is not None:
        result["readme_sketch"] = readme
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    tmp.replace(args.out)
    print(json.dumps(summary, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
