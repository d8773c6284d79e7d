"""The implicit loop model of pose data with effects (docs/effects.md): the leg readings
predicted at corrected readings (joints ``q + dq``, platform ``(p + dp, R exp([w]x))``) under
each pose's load and temperature, with their exact derivatives in every parameter (the geometric
errors, then the effects') and in the corrections.

It is the effects' contribution on top of the geometric model of the C++ core
(``_core.loop_jacobians``, ``cpp/src/implicit_loop.cpp``): ``s = D - l0 - sum of the effects'
changes``, with ``D``, ``l0`` and their derivatives from the core and the changes (the
compliance's ``c f`` under the pose's load, the thermal ``alpha D (T - T_ref)``) from the effects
(:meth:`iwr.effects.Effect.leg_change`), whose state (:class:`iwr.effects.LegState`) is
differentiated here in the geometric errors *and* the corrections: the leg forces change with
the platform's pose, its orientation turns the loads' moment arms, and the legs' lengths change
with both.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _core
from ..transforms import pose_matrix, rotvec_matrix
from . import LegState
from .model import (
    _compliance,
    _skew,
    check_inputs,
    joint_changes,
    joint_effects,
    leg_forces,
    leg_vectors_at,
    loads,
    split,
)

__all__ = ["loop_jacobians", "right_jacobian"]


def right_jacobian(w: np.ndarray) -> np.ndarray:
    """The right Jacobian ``J_r(w)`` (..., 3, 3) of SO(3) at rotation vectors ``w`` (..., 3):
    ``exp([w + d]x) = exp([w]x) exp([J_r d]x) + O(d^2)``; series below 1e-4 rad (as the C++
    core's ``so3_exp``)."""
    t2 = np.sum(w * w, axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    c = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(ts)) / ts**2)
    e = np.where(small, 1.0 / 6 - t2 / 120 + t2 * t2 / 5040, (ts - np.sin(ts)) / ts**3)
    k = _skew(w)
    return np.eye(3) - c[..., None, None] * k + e[..., None, None] * (k @ k)


def loop_jacobians(robot: Any, x: Any, q: np.ndarray, poses: np.ndarray, data: Any,
                   corrections: Any = None, *, joint_derivative: bool = False) -> Any:
    """:func:`iwr.implicit_loop.loop_jacobians` for a robot with effects: the predicted leg
    readings (N, 6) at corrected readings under ``data``'s loads and temperatures (an object
    with ``payload`` and ``temperatures`` as :class:`iwr.Measurements` has), their derivatives
    in ``x`` (N, 6, n_params + the effects' parameters) and in the corrections ``(dq, dp, w)``
    (N, 6, n_joints + 6). With ``joint_derivative``, also the readings' derivative in the
    carriage's *true* joint values (N, 6, n_joints): the one in the corrections ``dq`` before the
    chain rule through the effects' joint change (the same when no effect changes the joints);
    what a derivative of that change in anything else goes through."""
    xg, xe = split(robot, x)
    xg = np.ascontiguousarray(xg)
    n, nj, ng = len(poses), robot.n_joints, robot.n_params
    ny = nj + 6
    corr = np.zeros((n, ny)) if corrections is None else np.asarray(corrections, dtype=float)
    check_inputs(robot, data)
    on_joints = bool(joint_effects(robot))
    if on_joints:
        # The carriage at its true joint values: its joints' change under the load at the
        # corrected readings, added to the joint corrections (everything below then follows).
        t5 = pose_matrix(poses)
        w = corr[:, nj + 3:]
        t5[:, :3, :3] = t5[:, :3, :3] @ rotvec_matrix(w)
        t5[:, :3, 3] += corr[:, nj: nj + 3]
        dq, dq_z, dq_e = joint_changes(robot, xg, xe, q + corr[:, :nj], t5, data,
                                       right_jacobian(w))
        corr = corr.copy()
        corr[:, :nj] += dq
        corrections = corr
    # The geometry: legs = D - l0 and its derivatives, from the C++ core.
    legs, jx_g, jy = _core.loop_jacobians(robot._geometry, xg, q, poses,
                                          np.zeros((0, 0)) if corrections is None else corr)
    legs = legs.copy()
    jx_g = jx_g.reshape(n, 6, ng)
    jy = jy.reshape(n, 6, ny).copy()
    nc = 4 * nj
    off = slice(nc + 36, nc + 42)
    lengths = legs + robot.leg_offsets + xg[off]
    # The state's derivatives are taken in z = (x_geometric, dq, dp, w).
    d_len = np.concatenate([jx_g, jy], axis=2)
    d_len[:, :, off] += np.eye(6)
    needs: set[str] = set()
    for e in robot.effects:
        needs |= e.needs
    forces = d_forces = None
    if "forces" in needs:
        forces, d_forces = _forces(robot, xg, q, poses, corr, data)
    temps = None
    if "temperatures" in needs:
        temps = np.broadcast_to(data.temperatures, (n, 6))
    state = LegState(lengths, d_len, forces, d_forces, temps)
    jx = np.zeros((n, 6, ng + xe.size))
    jx[..., :ng] = jx_g
    col = 0
    for e in robot.effects:
        k = len(e.parameter_names())
        if "legs" in e.changes:
            change, d_z, d_own = e.leg_change(state, e.values() + xe[col: col + k])
            legs -= change
            jx[..., :ng] -= d_z[..., :ng]
            jy -= d_z[..., ng:]
            jx[..., ng + col: ng + col + k] -= d_own
        col += k
    jq = jy[..., :nj].copy()
    if on_joints:  # the chain rule through the joints' change
        jx[..., :ng] += np.einsum("kji,kip->kjp", jq, dq_z[..., :ng])
        jx[..., ng:] += np.einsum("kji,kip->kjp", jq, dq_e)
        jy += np.einsum("kji,kip->kjp", jq, dq_z[..., ng:])
    return (legs, jx, jy, jq) if joint_derivative else (legs, jx, jy)


def _forces(robot: Any, xg: np.ndarray, q: np.ndarray, poses: np.ndarray, corr: np.ndarray,
            data: Any) -> tuple[np.ndarray, np.ndarray]:
    """The leg forces at the corrected readings and their derivatives in
    ``(x_geometric, dq, dp, w)`` (N, 6, n_params + n_joints + 6)."""
    n, nj, ng = len(poses), robot.n_joints, robot.n_params
    nc = 4 * nj
    dq, dp, w = corr[:, :nj], corr[:, nj: nj + 3], corr[:, nj + 3:]
    t5 = pose_matrix(poses)
    t5[:, :3, :3] = t5[:, :3, :3] @ rotvec_matrix(w)
    t5[:, :3, 3] += dp
    rot = t5[:, :3, :3]
    v, dv_g, r = leg_vectors_at(robot, xg, q + dq, t5)
    jr = right_jacobian(w)
    plat = robot.platform_joints + xg[nc + 18: nc + 36].reshape(6, 3)
    nz = ng + nj + 6
    dv = np.zeros((n, 6, 3, nz))
    dv[..., :ng] = dv_g
    for i, kind in enumerate(robot.joint_types):  # a joint reading adds to d (P) or theta (R)
        dv[..., ng + i] = dv_g[..., 4 * i + (2 if kind == "P" else 3)]
    dv[..., ng + nj: ng + nj + 3] = np.eye(3)
    # d (R exp([w]x) b) / dw = -R exp([w]x) [b]x J_r(w)
    d_arm_w = -np.einsum("kab,jbc,kcd->kjad", rot, _skew(plat), jr)
    dv[..., ng + nj + 3:] = d_arm_w
    dr = np.zeros_like(dv)
    for j in range(6):
        dr[:, j, :, nc + 18 + 3 * j: nc + 21 + 3 * j] = rot
    dr[..., ng + nj + 3:] = d_arm_w
    # d (R exp([w]x)) / dw_c = R exp([w]x) [J_r e_c]x
    d_rot = np.zeros((n, 3, 3, nz))
    d_rot[..., ng + nj + 3:] = np.einsum("kab,kcbd->kadc", rot,
                                         _skew(np.swapaxes(jr, 1, 2)))
    comp = _compliance(robot)
    masses, centres = loads(comp, data, n)
    return leg_forces(v, dv, r, dr, rot, masses, centres, comp.gravity, d_rot)
