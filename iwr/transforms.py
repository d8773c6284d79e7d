"""Rotations and poses: Z-Y-X Euler angles (eq. 6), homogeneous transforms, small rotations."""

from __future__ import annotations

import numpy as np

__all__ = ["euler_zyx", "euler_from_matrix", "pose_matrix", "pose_from_matrix", "rotation_angle",
           "rotvec_matrix", "skew"]


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` (..., 3, 3) of vectors (..., 3): ``[v]x u = v x u``."""
    v = np.asarray(v, dtype=float)
    k = np.zeros(v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return k


def euler_zyx(alpha, beta, gamma) -> np.ndarray:
    """``Rz(alpha) Ry(beta) Rx(gamma)`` (eq. 6); broadcasts, returning shape (..., 3, 3)."""
    a, b, g = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (alpha, beta, gamma)))
    ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
    r = np.empty(a.shape + (3, 3))
    r[..., 0, 0] = ca * cb
    r[..., 0, 1] = ca * sb * sg - sa * cg
    r[..., 0, 2] = ca * sb * cg + sa * sg
    r[..., 1, 0] = sa * cb
    r[..., 1, 1] = sa * sb * sg + ca * cg
    r[..., 1, 2] = sa * sb * cg - ca * sg
    r[..., 2, 0] = -sb
    r[..., 2, 1] = cb * sg
    r[..., 2, 2] = cb * cg
    return r


def euler_from_matrix(r) -> np.ndarray:
    """Z-Y-X Euler angles ``(alpha, beta, gamma)`` of rotation matrices (..., 3, 3), with beta in
    [-pi/2, pi/2], exact also at and near the gimbal lock beta = +-pi/2: gamma is read from
    ``Rz(-alpha) R = Ry(beta) Rx(gamma)`` (its second row is ``(0, cos gamma, -sin gamma)``), so
    it carries whatever turn alpha does not; at the lock itself (``cos beta = 0`` exactly)
    ``alpha = 0``."""
    r = np.asarray(r, dtype=float)
    cb = np.hypot(r[..., 0, 0], r[..., 1, 0])
    beta = np.arctan2(-r[..., 2, 0], cb)
    alpha = np.arctan2(r[..., 1, 0], r[..., 0, 0])  # 0 where cos(beta) = 0
    ca, sa = np.cos(alpha), np.sin(alpha)
    gamma = np.arctan2(sa * r[..., 0, 2] - ca * r[..., 1, 2], ca * r[..., 1, 1] - sa * r[..., 0, 1])
    return np.stack([alpha, beta, gamma], axis=-1)


def pose_matrix(pose) -> np.ndarray:
    """Homogeneous transforms (..., 4, 4) of poses (..., 6) ``(x, y, z, alpha, beta, gamma)``."""
    pose = np.asarray(pose, dtype=float)
    t = np.zeros(pose.shape[:-1] + (4, 4))
    t[..., :3, :3] = euler_zyx(pose[..., 3], pose[..., 4], pose[..., 5])
    t[..., :3, 3] = pose[..., :3]
    t[..., 3, 3] = 1.0
    return t


def pose_from_matrix(t) -> np.ndarray:
    """Poses (..., 6) of homogeneous transforms (..., 4, 4)."""
    t = np.asarray(t, dtype=float)
    return np.concatenate([t[..., :3, 3], euler_from_matrix(t[..., :3, :3])], axis=-1)


def rotation_angle(r) -> np.ndarray:
    """The angle (rad, in [0, pi]) of rotation matrices (..., 3, 3): ``atan2(|sin theta axis|,
    cos theta)`` from the skew part and the trace, accurate near 0 and pi, unlike
    ``arccos((trace - 1) / 2)``; independent of any Euler angles (and so of their gimbal
    lock). The error between two orientations is the angle of ``Ra^T Rb``."""
    r = np.asarray(r, dtype=float)
    sin_axis = 0.5 * np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                               r[..., 1, 0] - r[..., 0, 1]], axis=-1)
    cos = 0.5 * (np.trace(r, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(np.linalg.norm(sin_axis, axis=-1), cos)


def rotvec_matrix(w) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) (Rodrigues' formula)."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    k = np.zeros(w.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    small = theta < 1e-12
    safe = np.where(small, 1.0, theta)
    s = np.where(small, 1.0, np.sin(safe) / safe)
    c = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + s * k + c * (k @ k)
