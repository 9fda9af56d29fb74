"""The one position IK of the arm layer: damped least squares on a site's pose, for start postures and homes.

:func:`~seqmotion.sim.control.solve_ik` (a scene's start posture for a tool pose) and
:func:`~seqmotion.sim.robot_models.solve_pose` (a robot's home, a posture for a pen pose) both call
:func:`damped_least_squares`; they differ only in what they pass (step cap, tolerance, joint bounds). The
controller's per-period differential IK (mink) is another job: one step toward a moving target.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .backend import import_mujoco


def damped_least_squares(
    model: Any,
    data: Any,
    site: int,
    qpos_adr: Any,
    dof_adr: Any,
    pos: np.ndarray,
    quat: np.ndarray,
    seed: np.ndarray,
    *,
    iterations: int = 300,
    tolerance: float = 1e-9,
    max_step: float = 0.5,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    attitude_from_matrix: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles that put the site ``site`` at ``pos`` ``(3,)`` [m] with attitude ``quat`` ``(4,)`` (w, x, y, z).

    Damped Gauss–Newton from ``seed``: each iteration moves by ``J⁺ e`` (``J Jᵀ`` damped by 1e-6), scaled so no
    joint moves more than ``max_step`` [rad], and clamped to ``bounds`` when given (the seed too). Only the
    joints at ``qpos_adr`` / ``dof_adr`` move; ``data``'s other coordinates stay as they are.

    Args:
        model, data: the compiled model and a scratch ``MjData`` of it (its ``qpos`` is overwritten).
        site: the site's id.
        qpos_adr, dof_adr: the joints' addresses in ``qpos`` and in the velocity vector.
        iterations: at most this many steps.
        tolerance: stop once the residual's norm is below this.
        bounds: ``(lower, upper)`` joint angles [rad] the solution stays within.
        attitude_from_matrix: read the site's attitude from its rotation matrix (``site_xmat``) instead of its
            quaternion (``site_xquat``); the two agree to rounding, and each caller keeps the reading it was
            calibrated with.

    Returns:
        The joint angles and the last residual ``(6,)``: position [m] and attitude [rad] error in the world frame.
    """
    mujoco = import_mujoco()
    lower, upper = (None, None) if bounds is None else bounds
    q = np.array(seed, dtype=np.float64)
    if bounds is not None:
        q = np.clip(q, lower, upper)
    jac = np.zeros((6, model.nv))
    err_rot, current = np.zeros(3), np.zeros(4)
    err = np.full(6, np.inf)
    for _ in range(iterations):
        data.qpos[qpos_adr] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        if attitude_from_matrix:
            mujoco.mju_mat2Quat(current, data.site_xmat[site])
        else:
            current = data.site_xquat[site]
        mujoco.mju_subQuat(err_rot, quat, current)
        err = np.concatenate([pos - data.site_xpos[site], data.site_xmat[site].reshape(3, 3) @ err_rot])
        if np.linalg.norm(err) < tolerance:
            break
        mujoco.mj_jacSite(model, data, jac[:3], jac[3:], site)
        j = jac[:, dof_adr]
        step = j.T @ np.linalg.solve(j @ j.T + 1e-6 * np.eye(6), err)
        q = q + step * min(1.0, max_step / max(np.abs(step).max(), 1e-12))
        if bounds is not None:
            q = np.clip(q, lower, upper)
    return q, err


__all__ = ["damped_least_squares"]
