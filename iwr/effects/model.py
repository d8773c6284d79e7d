"""The legs' geometry and statics with their exact derivatives in the geometric errors, and the
leg readings of a robot with effects (docs/effects.md).

Everything here is vectorised over the poses in numpy; the leg lengths agree with the C++ core's
(:func:`iwr.problem.predict_legs`) to round-off, which a test checks.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..transforms import pose_matrix
from ..transforms import skew as _skew
from . import JointState, LegState

__all__ = ["SingularPoseError", "carriage_and_derivatives", "joint_changes", "joint_loads",
           "leg_forces", "leg_state", "leg_vectors", "leg_vectors_at", "predicted_readings",
           "split", "without_singular"]


def _dh(alpha: np.ndarray, a: np.ndarray, d: np.ndarray, theta: np.ndarray,
        derivatives: bool = True) -> tuple[np.ndarray, Any]:
    """Standard DH transforms ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` (N, 4, 4) and their derivatives
    in (alpha, a, d, theta), shape (4, N, 4, 4) (None without ``derivatives``)."""
    ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
    n = alpha.shape[0]
    t = np.zeros((n, 4, 4))
    t[:, 0] = np.stack([ct, -st * ca, st * sa, a * ct], axis=1)
    t[:, 1] = np.stack([st, ct * ca, -ct * sa, a * st], axis=1)
    t[:, 2] = np.stack([np.zeros(n), sa, ca, d], axis=1)
    t[:, 3, 3] = 1.0
    if not derivatives:
        return t, None
    dt = np.zeros((4, n, 4, 4))
    z = np.zeros(n)
    dt[0, :, 0] = np.stack([z, st * sa, st * ca, z], axis=1)       # alpha
    dt[0, :, 1] = np.stack([z, -ct * sa, -ct * ca, z], axis=1)
    dt[0, :, 2] = np.stack([z, ca, -sa, z], axis=1)
    dt[1, :, 0, 3], dt[1, :, 1, 3] = ct, st                        # a
    dt[2, :, 2, 3] = 1.0                                           # d
    dt[3, :, 0] = np.stack([-st, -ct * ca, ct * sa, -a * st], axis=1)  # theta
    dt[3, :, 1] = np.stack([ct, -st * ca, st * sa, a * ct], axis=1)
    return t, dt


def _links(robot: Any, x: np.ndarray, q: np.ndarray, derivatives: bool = True
           ) -> tuple[list[Any], list[Any]]:
    """Each carriage joint's DH transform (N, 4, 4) and its derivatives in its (alpha, a, d,
    theta) (4, N, 4, 4; None without ``derivatives``), errors ``x`` added and the readings ``q``
    to d or theta."""
    n_poses, nj = q.shape[0], robot.n_joints
    dh = robot.dh + x[: 4 * nj].reshape(nj, 4)
    mats, ders = [], []
    for i, kind in enumerate(robot.joint_types):
        col = np.broadcast_to(dh[i], (n_poses, 4)).copy()
        col[:, 2 if kind == "P" else 3] += q[:, i]
        t, dt = _dh(col[:, 0], col[:, 1], col[:, 2], col[:, 3], derivatives)
        mats.append(t)
        ders.append(dt)
    return mats, ders


def joint_columns(robot: Any) -> list[int]:
    """The geometric error columns a joint reading adds to: d (prismatic) or theta (revolute)
    of each joint, so that a derivative in the reading is the one in that column."""
    return [4 * i + (2 if kind == "P" else 3) for i, kind in enumerate(robot.joint_types)]


def joint_loads(robot: Any, xg: np.ndarray, q: np.ndarray, moment: np.ndarray,
                mass: np.ndarray, loaded: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(loads, d_geometric, d_moment)``: the gravity load of each carriage joint (N, n_joints)
    at readings ``q`` (:class:`iwr.effects.JointState`: N mm about a revolute axis, N along a
    prismatic one), its derivatives in the carriage's 4 n error parameters and the base joints'
    18 (N, n_joints, 4 n + 18) and in ``moment`` (N, n_joints, 3).

    The distal bodies are the hexapod (``loaded.hexapod_mass`` kg, centre
    ``loaded.hexapod_centre`` mm from the centre of its base joints, in {4}'s axes) and the
    bodies the platform carries, given by their
    total ``mass`` (N,) kg and first moment ``moment`` (N, 3) kg mm in {0} (sum of mass times
    centre). With ``P`` the first moment of all of them and ``M`` their mass, joint i's axis
    ``z`` through ``o`` (frame {i-1} of the DH chain): the torque about the axis is
    ``z . ((P - M o) x M g) / M = (P - M o) . (g x z)``, the axial force ``M g . z``."""
    n, nj = q.shape[0], robot.n_joints
    nc = 4 * nj
    g = np.asarray(loaded.gravity, dtype=float)
    mats, ders = _links(robot, xg, q)
    frame = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    d_frame = np.zeros((nc, n, 4, 4))
    axes, d_axes, origins, d_origins = [], [], [], []
    for i in range(nj):
        axes.append(frame[:, :3, 2].copy())
        origins.append(frame[:, :3, 3].copy())
        d_axes.append(d_frame[:, :, :3, 2].copy())
        d_origins.append(d_frame[:, :, :3, 3].copy())
        d_frame = d_frame @ mats[i]
        d_frame[4 * i: 4 * i + 4] = frame[None] @ ders[i]
        frame = frame @ mats[i]
    # The hexapod's centre: given in the frame its base joints define (base_frame), so that
    # the geometry's null directions (frame {4} moved or turned, the base joints moved back in
    # it) leave it where it is.
    ch, d_ch = base_centre(robot.base_joints + xg[nc: nc + 18].reshape(6, 3),
                           np.asarray(loaded.hexapod_centre, dtype=float))
    mh = float(loaded.hexapod_mass)
    p_all = mh * (frame[:, :3, :3] @ ch + frame[:, :3, 3]) + moment
    d_p = np.concatenate([mh * (d_frame[:, :, :3, :3] @ ch + d_frame[:, :, :3, 3]),
                          mh * np.einsum("kab,bp->pka", frame[:, :3, :3], d_ch)])
    d_origins = [np.concatenate([d, np.zeros((18,) + d.shape[1:])]) for d in d_origins]
    d_axes = [np.concatenate([d, np.zeros((18,) + d.shape[1:])]) for d in d_axes]
    m_all = mh + mass
    out = np.zeros((n, nj))
    d_dh = np.zeros((n, nj, nc + 18))
    d_mom = np.zeros((n, nj, 3))
    for i, kind in enumerate(robot.joint_types):
        if kind == "R":
            gz = np.cross(g, axes[i])
            arm = p_all - m_all[:, None] * origins[i]
            out[:, i] = np.sum(arm * gz, axis=1)
            d_arm = d_p - m_all[None, :, None] * d_origins[i]
            d_dh[:, i] = (np.sum(d_arm * gz, axis=2)
                          + np.sum(arm * np.cross(g, d_axes[i]), axis=2)).T
            d_mom[:, i] = gz
        else:
            out[:, i] = m_all * (axes[i] @ g)
            d_dh[:, i] = (m_all * (d_axes[i] @ g)).T
    return out, d_dh, d_mom


def base_frame(base: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(centre, axes, d_centre, d_axes)``: the frame the six base joints ``base`` (6, 3, in
    {4}) define, and its derivatives in them (3, 18) and (3, 3, 18): its origin their centre,
    its z axis the normal of their polygon (``sum a_j x a_j+1``, right-handed with their order),
    its x axis towards the midpoint of joints 1 and 2, in the polygon's plane. ``axes`` holds
    the unit vectors as columns (a rotation); on the IWR it is {4} itself."""
    eye = np.eye(3)
    centre = base.mean(axis=0)
    d_centre = np.tile(eye / 6, (1, 6))
    nxt = np.roll(base, -1, axis=0)
    big_n = np.cross(base, nxt).sum(axis=0)
    d_big_n = np.zeros((3, 18))
    for j in range(6):  # d (a_j x a_j+1) / d a_j = -[a_j+1]x, / d a_j+1 = [a_j]x
        d_big_n[:, 3 * j: 3 * j + 3] += -_skew(nxt[j])
        k = (j + 1) % 6
        d_big_n[:, 3 * k: 3 * k + 3] += _skew(base[j])
    z, d_z = _unit(big_n, d_big_n)
    m = 0.5 * (base[0] + base[1]) - centre
    d_m = -d_centre
    d_m[:, 0:3] += 0.5 * eye
    d_m[:, 3:6] += 0.5 * eye
    big_x = m - (m @ z) * z
    d_big_x = d_m - np.outer(z, z @ d_m + m @ d_z) - (m @ z) * d_z
    x, d_x = _unit(big_x, d_big_x)
    y = np.cross(z, x)
    d_y = np.cross(d_z.T, x).T + np.cross(z, d_x.T).T
    return centre, np.column_stack([x, y, z]), d_centre, np.stack([d_x, d_y, d_z], axis=1)


def _unit(v: np.ndarray, dv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``v / |v|`` and its derivative, from ``v``'s (3, p)."""
    norm = float(np.linalg.norm(v))
    if not norm > 0:
        raise ValueError("base joints: they span no plane (the hexapod's base frame is "
                         "undefined)")
    u = v / norm
    return u, (dv - np.outer(u, u @ dv)) / norm


def base_centre(base: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The hexapod's centre of mass in {4} (3,) at ``offset`` in the base joints' frame
    (:func:`base_frame`), and its derivatives in the base joints (3, 18)."""
    centre, axes, d_centre, d_axes = base_frame(base)
    return centre + axes @ offset, d_centre + np.einsum("acp,c->ap", d_axes, offset)


def platform_moment(loaded: Any, data: Any, t5: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                        np.ndarray]:
    """``(moment, mass, centre_moment)``: the first moment in {0} (N, 3) kg mm and the mass
    (N,) kg of the bodies the platform carries (the platform of ``loaded``, ``data``'s payload)
    at platform transforms ``t5``, and their first moment in {5} (N, 3) (the derivative of
    the first one in the platform's orientation is ``R [that]x``)."""
    masses, centres = loads(loaded, data, len(t5))
    c5 = np.einsum("kb,kba->ka", masses, centres)
    mass = masses.sum(axis=1)
    moment = np.einsum("kab,kb->ka", t5[:, :3, :3], c5) + mass[:, None] * t5[:, :3, 3]
    return moment, mass, c5


def carriage_and_derivatives(robot: Any, x: np.ndarray, q: np.ndarray
                             ) -> tuple[np.ndarray, np.ndarray]:
    """``0T4`` at each pose (N, 4, 4) and its derivatives in the carriage's 4 n error parameters
    (4 n, N, 4, 4), errors ``x`` (the geometric ones) added as :meth:`iwr.Robot.with_errors`
    does and the joint readings to ``d`` (prismatic) or ``theta`` (revolute)."""
    n_poses, nj = q.shape[0], robot.n_joints
    mats, ders = _links(robot, x, q)
    eye = np.broadcast_to(np.eye(4), (n_poses, 4, 4))
    prefix = [eye]
    for t in mats:
        prefix.append(prefix[-1] @ t)
    suffix = [eye]
    for t in reversed(mats):
        suffix.insert(0, t @ suffix[0])
    d_total = np.zeros((4 * nj, n_poses, 4, 4))
    for i in range(nj):
        for c in range(4):
            d_total[4 * i + c] = prefix[i] @ ders[i][c] @ suffix[i + 1]
    return prefix[-1], d_total


def split(robot: Any, x: Any) -> tuple[np.ndarray, np.ndarray]:
    """``x`` (geometric errors, then the effects' parameters) as ``(geometric, effects)``."""
    x = np.asarray(x, dtype=float)
    n_eff = sum(len(e.parameter_names()) for e in robot.effects)
    if x.shape != (robot.n_params + n_eff,):
        raise ValueError(f"x: shape {x.shape}; expected ({robot.n_params + n_eff},): "
                         f"{robot.n_params} geometric errors, then {n_eff} effect parameters")
    return x[: robot.n_params], x[robot.n_params:]


def leg_vectors(robot: Any, xg: np.ndarray, q: np.ndarray, poses: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(v, dv, r)``: the leg vectors from each U-joint to its S-joint in {0} (N, 6, 3), their
    derivatives in the geometric errors (N, 6, 3, n_params), and the S-joints' positions
    relative to the platform origin, in {0} (N, 6, 3), at platform poses ``poses`` in {0}."""
    return leg_vectors_at(robot, xg, q, pose_matrix(poses))


def leg_vectors_at(robot: Any, xg: np.ndarray, q: np.ndarray, t5: np.ndarray, *,
                   derivatives: bool = True) -> tuple[np.ndarray, Any, np.ndarray]:
    """:func:`leg_vectors` at platform transforms ``t5`` (N, 4, 4) in {0}; without
    ``derivatives``, ``dv`` is None (and the carriage's derivatives are not computed)."""
    n, nc = len(t5), 4 * robot.n_joints
    if derivatives:
        t4, dt4 = carriage_and_derivatives(robot, xg, q)
    else:
        t4 = np.broadcast_to(np.eye(4), (n, 4, 4))
        for t in _links(robot, xg, q, derivatives=False)[0]:
            t4 = t4 @ t
    base = robot.base_joints + xg[nc: nc + 18].reshape(6, 3)
    plat = robot.platform_joints + xg[nc + 18: nc + 36].reshape(6, 3)
    r = np.einsum("kab,jb->kja", t5[:, :3, :3], plat)
    a0 = t4[:, None, :3, 3] + np.einsum("kab,jb->kja", t4[:, :3, :3], base)
    v = t5[:, None, :3, 3] + r - a0
    if not derivatives:
        return v, None, r
    dv = np.zeros((n, 6, 3, robot.n_params))
    if nc:
        dcar = dt4[:, :, None, :3, 3] + np.einsum("pkab,jb->pkja", dt4[:, :, :3, :3], base)
        dv[..., :nc] = -np.moveaxis(dcar, 0, -1)
    for j in range(6):
        dv[:, j, :, nc + 3 * j: nc + 3 * j + 3] = -t4[:, :3, :3]
        dv[:, j, :, nc + 18 + 3 * j: nc + 18 + 3 * j + 3] = t5[:, :3, :3]
    return v, dv, r


class SingularPoseError(ValueError):
    """:func:`leg_forces` at a pose where the hexapod is singular (its legs cannot hold a load):
    ``pose``, the pose's index among those of the call."""

    def __init__(self, message: str, pose: int) -> None:
        super().__init__(message)
        self.pose = pose


def without_singular(evaluate: Any, live: np.ndarray, ok: np.ndarray, poses: np.ndarray
                     ) -> tuple[Any, np.ndarray]:
    """``(evaluate(kept), kept)``: ``evaluate`` of the poses ``live`` (indices), leaving out one
    by one those at which the hexapod is singular (:class:`SingularPoseError`): the forward
    kinematics with the effects fails there, as the C++ objectives' does, instead of stopping
    the search that tried such a robot; each pose left out is marked so in ``ok`` (False) and
    ``poses`` (NaN). ``(None, empty)`` when none is left."""
    kept = live
    while kept.size:
        try:
            return evaluate(kept), kept
        except SingularPoseError as err:
            ok[kept[err.pose]], poses[kept[err.pose]] = False, np.nan
            kept = np.delete(kept, err.pose)
    return None, kept


def leg_forces(v: np.ndarray, dv: np.ndarray | None, r: np.ndarray, dr: np.ndarray | None,
               rotations: np.ndarray, masses: np.ndarray, centres: np.ndarray,
               gravity: np.ndarray, d_rotations: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray | None]:
    """The axial leg forces (N, 6) that hold the platform in equilibrium under gravity, tension
    positive, and their derivatives (N, 6, n) when ``dv``, ``dr`` (the derivatives of the leg
    vectors and of the S-joints' arms, (N, 6, 3, n)) are given.

    Statics of the massless legs (two-force members along their axes): ``G f = w`` with column
    j of G the leg's unit vector ``u_j`` and its moment ``r_j x u_j`` about the platform origin
    (``G = J^T``, J the leg Jacobian of the platform twist: ``dL = J (dP, dphi)``), and ``w``
    the gravity wrench of the bodies ``(sum m_b g, sum (R c_b) x m_b g)`` (N, N mm). So
    ``f = J^-T w``: with the virtual work ``f . dL = w . dX`` (a test checks it against the
    change of the bodies' potential energy). ``masses`` (N, B) kg, ``centres`` (N, B, 3) mm in
    {5}, ``rotations`` (N, 3, 3) the platform's orientation in {0}, ``gravity`` (3,) m/s^2 in
    {0}; ``d_rotations`` (N, 3, 3, n), optional: the derivatives of ``rotations`` in the same
    variables (the platform's orientation among them: the loads' moment arms turn with it)."""
    length = np.linalg.norm(v, axis=2)
    u = v / length[..., None]
    g_mat = np.concatenate([u, np.cross(r, u)], axis=2).transpose(0, 2, 1)  # (N, 6, 6)
    weight = masses[..., None] * gravity  # (N, B, 3)
    arm = np.einsum("kab,kcb->kca", rotations, centres)
    wrench = np.concatenate([weight.sum(axis=1), np.cross(arm, weight).sum(axis=1)], axis=1)
    cond = np.linalg.cond(g_mat)
    if not np.all(np.isfinite(cond)) or np.any(cond > 1e12):
        k = int(np.argmax(np.where(np.isfinite(cond), cond, np.inf)))
        raise SingularPoseError(f"pose {k}: the hexapod is singular there (leg Jacobian "
                                f"condition number {cond[k]:.3g}): the legs cannot hold a load",
                                k)
    f = np.linalg.solve(g_mat, wrench[..., None])[..., 0]
    if dv is None:
        return f, None
    assert dr is not None
    du = (dv - u[..., None] * np.einsum("kja,kjap->kjp", u, dv)[:, :, None, :]) \
        / length[..., None, None]
    dmom = (np.cross(dr, u[..., None], axisa=2, axisb=2, axisc=2)
            + np.cross(r[..., None], du, axisa=2, axisb=2, axisc=2))
    dg_f = np.concatenate([np.einsum("kjap,kj->kap", du, f),
                           np.einsum("kjap,kj->kap", dmom, f)], axis=1)  # (N, 6, n)
    if d_rotations is not None:
        # The gravity moment turns with the platform: d (R c) x m g.
        d_arm = np.einsum("kabp,kcb->kcap", d_rotations, centres)
        dg_f[:, 3:] -= np.cross(d_arm, weight[..., None], axisa=2, axisb=2,
                                axisc=2).sum(axis=1)
    df = -np.linalg.solve(g_mat, dg_f)
    return f, df


def leg_state(robot: Any, xg: np.ndarray, q: np.ndarray, poses: np.ndarray, data: Any,
              needs: frozenset[str] | set[str] = frozenset({"forces", "temperatures"})
              ) -> LegState:
    """The :class:`iwr.effects.LegState` of ``data``'s loads and temperatures (``data`` with
    optional ``payload`` (N, 4) and ``temperatures`` (N, 1) or (N, 6)) at poses ``poses`` in
    {0}, geometric errors ``xg``; the forces only when ``"forces"`` is needed."""
    v, dv, r = leg_vectors(robot, xg, q, poses)
    length = np.linalg.norm(v, axis=2)
    u = v / length[..., None]
    d_length = np.einsum("kja,kjap->kjp", u, dv)
    forces = d_forces = None
    if "forces" in needs:
        comp = _compliance(robot)
        nc = 4 * robot.n_joints
        rot = pose_matrix(poses)[:, :3, :3]
        dr = np.zeros_like(dv)
        for j in range(6):
            dr[:, j, :, nc + 18 + 3 * j: nc + 18 + 3 * j + 3] = rot
        masses, centres = loads(comp, data, len(poses))
        forces, d_forces = leg_forces(v, dv, r, dr, rot, masses, centres, comp.gravity)
    temps = None
    if "temperatures" in needs:
        t = getattr(data, "temperatures", None)
        if t is not None:
            temps = np.broadcast_to(t, (len(poses), 6))
    return LegState(length, d_length, forces, d_forces, temps)


def loads(comp: Any, data: Any, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The bodies the legs hold at each of ``n`` poses: masses (N, B) kg and centres of mass in
    {5} (N, B, 3) mm, the platform's (of the compliance effect ``comp``), then ``data``'s
    payload if it has one."""
    payload = getattr(data, "payload", None)
    masses = np.full((n, 1), comp.platform_mass)
    centres = np.broadcast_to(comp.platform_centre, (n, 1, 3))
    if payload is not None:
        masses = np.hstack([masses, payload[:, :1]])
        centres = np.concatenate([centres, payload[:, None, 1:]], axis=1)
    return masses, centres


def _compliance(robot: Any) -> Any:
    """The robot's compliance effect (which holds the statics' gravity and platform mass)."""
    for e in robot.effects:
        if hasattr(e, "gravity"):
            return e
    raise ValueError(f"robot {robot.name!r}: no effect describes the loads (gravity, platform "
                     "mass): switch on [effects.compliance]")


def check_inputs(robot: Any, data: Any, where: str = "measurements") -> None:
    """ValueError unless ``data`` holds what the robot's effects need (temperatures: the
    machine's one per pose for an effect that needs ``"machine_temperature"``)."""
    temps = getattr(data, "temperatures", None)
    for e in robot.effects:
        if "temperatures" in e.needs and temps is None:
            raise ValueError(
                f"{where}: the {e.name} effect ({e.description}) needs each pose's "
                "temperature: columns T_C (one per pose) or T1_C .. T6_C (one per leg), "
                "degrees C (docs/effects.md)")
        if "machine_temperature" in e.needs and (temps is None or np.shape(temps)[1:] != (1,)):
            found = ("none" if temps is None else
                     "one per leg (T1_C .. T6_C), not the machine's")
            raise ValueError(
                f"{where}: the {e.name} effect ({e.description}) needs the machine's "
                f"temperature at each pose: column T_C, degrees C (docs/effects.md); the data "
                f"have {found}")


def joint_effects(robot: Any) -> list[Any]:
    """The robot's effects that change the carriage's joints."""
    return [e for e in robot.effects if "joints" in e.changes]


def _loaded(robot: Any) -> Any:
    """The robot's effect on the joints that describes the loads (gravity, the hexapod), or None
    when no effect on the joints needs them."""
    for e in joint_effects(robot):
        if hasattr(e, "hexapod_mass"):
            return e
    if any("loads" in e.needs for e in joint_effects(robot)):
        raise ValueError(f"robot {robot.name!r}: no effect describes the carriage's loads")
    return None


def joint_changes(robot: Any, xg: np.ndarray, xe: np.ndarray, q: np.ndarray, t5: np.ndarray,
                  data: Any, right_jacobians: Any = None, *, loads_only: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(change, d_z, d_own)``: the effects' change of the carriage's joint values (N,
    n_joints) at readings ``q`` and platform transforms ``t5`` under ``data``'s loads (and the
    machine's temperatures), its derivatives in ``z`` (N, n_joints, n_z) and in the effects'
    parameters (N, n_joints, len(xe); zero for the effects on the legs). ``z`` is the geometric
    errors, then, when ``right_jacobians`` (N, 3, 3) are given (the implicit loop: ``t5`` is the
    measured pose turned by rotation vectors ``w`` and moved; they are ``J_r(w)``,
    :func:`iwr.effects.loop.right_jacobian`), the corrections ``(dq, dp, w)``. With
    ``loads_only``, the change of the effects of the loads alone (those that need ``"loads"``:
    what is linear in gravity)."""
    n, nj, ng = len(q), robot.n_joints, robot.n_params
    nc = 4 * nj
    n_z = ng if right_jacobians is None else ng + nj + 6
    d_loads = np.zeros((n, nj, n_z))
    torques = np.zeros((n, nj))
    loaded = _loaded(robot)
    if loaded is not None:
        moment, mass, c5 = platform_moment(loaded, data, t5)
        torques, d_dh, d_mom = joint_loads(robot, xg, q, moment, mass, loaded)
        d_loads[..., : nc + 18] = d_dh
        if right_jacobians is not None:
            d_loads[..., ng: ng + nj] = d_dh[..., joint_columns(robot)]
            d_loads[..., ng + nj: ng + nj + 3] = d_mom * mass[:, None, None]
            # d (R exp([w]x) c) / dw = -R exp([w]x) [c]x J_r(w), R exp([w]x) the rotation of t5.
            d_w = -np.einsum("kab,kbc,kcd->kad", t5[:, :3, :3], _skew(c5), right_jacobians)
            d_loads[..., ng + nj + 3:] = np.einsum("kia,kad->kid", d_mom, d_w)
    d_q = np.zeros((n, nj, n_z))
    if right_jacobians is not None:
        d_q[..., ng: ng + nj] = np.eye(nj)
    temps = getattr(data, "temperatures", None)
    if temps is not None and np.shape(temps)[1:] == (1,):
        temps = np.asarray(temps, dtype=float)[:, 0]
    else:
        temps = None
    state = JointState(torques, d_loads, robot.joint_types, q, d_q, temps)
    change = np.zeros((n, nj))
    d_z = np.zeros((n, nj, n_z))
    d_own = np.zeros((n, nj, xe.size))
    col = 0
    for e in robot.effects:
        k = len(e.parameter_names())
        if "joints" in e.changes and (not loads_only or "loads" in e.needs):
            c, dz, do = e.joint_change(state, e.values() + xe[col: col + k])
            change += c
            d_z += dz
            d_own[..., col: col + k] += do
        col += k
    return change, d_z, d_own


def predicted_readings(robot: Any, x: Any, q: Any, poses: Any, data: Any,
                       derivatives: bool = False) -> Any:
    """The leg sensor readings (N, 6) that the robot with geometric errors and effect
    parameters ``x`` (:func:`split`) gives at platform poses ``poses`` in {0}, under ``data``'s
    loads and temperatures: ``s = D - l0 - sum of the effects' changes``, D the distance
    between the joint centres. With ``derivatives``: also their Jacobian (N, 6, len(x))."""
    xg, xe = split(robot, x)
    q = np.asarray(q, dtype=float).reshape(len(poses), robot.n_joints)
    poses = np.asarray(poses, dtype=float)
    check_inputs(robot, data)
    on_joints = bool(joint_effects(robot))
    if on_joints:  # the carriage at its true joint values: the legs and their effects follow
        dq, dq_g, dq_e = joint_changes(robot, xg, xe, q, pose_matrix(poses), data)
        q = q + dq
    needs: set[str] = set()
    for e in robot.effects:
        needs |= e.needs
    state = leg_state(robot, xg, q, poses, data, needs)
    nc = 4 * robot.n_joints
    l0 = robot.leg_offsets + xg[nc + 36: nc + 42]
    s = state.lengths - l0
    jac = np.zeros((len(poses), 6, len(x)))
    jac[..., : robot.n_params] = state.d_lengths
    jac[..., nc + 36: nc + 42] -= np.eye(6)
    col = robot.n_params
    for e in robot.effects:
        k = len(e.parameter_names())
        if "legs" in e.changes:
            change, d_geo, d_own = e.leg_change(state, e.values() + xe[col - robot.n_params:
                                                                       col - robot.n_params + k])
            s = s - change
            jac[..., : robot.n_params] -= d_geo
            jac[..., col: col + k] -= d_own
        col += k
    if on_joints:  # the chain rule through the joints' change: d s / d q is its DH column's
        jq = jac[..., joint_columns(robot)]
        jac[..., : robot.n_params] += np.einsum("kji,kip->kjp", jq, dq_g)
        jac[..., robot.n_params:] += np.einsum("kji,kip->kjp", jq, dq_e)
    return (s, jac) if derivatives else s
