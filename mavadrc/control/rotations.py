"""Rotations: quaternions, rotation matrices, ZYX Euler angles and headings, for the control
laws, the bundled vehicle and the figures alike.

Conventions (MAVLink end to end): world NED, body FRD, quaternion [w, x, y, z] rotating body
vectors into NED, Euler angles ZYX (yaw, then pitch, then roll), radians.

The kernels write into arrays they are given and are compiled, for the hot paths (the vehicle's
firmware, the fast in-process flight); the forms that return new arrays call the same kernels,
so both give the same numbers to the last bit.
"""

import math

import numpy as np

from .jit import jit


@jit
def quat_to_rotmat(q, R):
    """R(q) (3, 3), body FRD -> NED, of a unit quaternion, written to R."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@jit
def quat_from_rotmat(r00, r01, r02, r10, r11, r12, r20, r21, r22, q):
    """Unit quaternion [w, x, y, z] of a rotation matrix (largest-pivot method), written to q."""
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q[0] = 0.25 * s
        q[1] = (r21 - r12) / s
        q[2] = (r02 - r20) / s
        q[3] = (r10 - r01) / s
    elif r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        q[0] = (r21 - r12) / s
        q[1] = 0.25 * s
        q[2] = (r01 + r10) / s
        q[3] = (r02 + r20) / s
    elif r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        q[0] = (r02 - r20) / s
        q[1] = (r01 + r10) / s
        q[2] = 0.25 * s
        q[3] = (r12 + r21) / s
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        q[0] = (r10 - r01) / s
        q[1] = (r02 + r20) / s
        q[2] = (r12 + r21) / s
        q[3] = 0.25 * s
    if q[0] < 0.0:  # one representative: w >= 0
        for i in range(4):
            q[i] = -q[i]


@jit
def quat_to_euler(q, e):
    """ZYX Euler angles (roll, pitch, yaw) of a unit quaternion, written to e."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    e[0] = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    sp = 2.0 * (w * y - z * x)
    if sp > 1.0:
        sp = 1.0
    elif sp < -1.0:
        sp = -1.0
    e[1] = math.asin(sp)
    e[2] = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


@jit
def euler_to_quat(roll, pitch, yaw, q):
    """Quaternion of ZYX Euler angles, written to q."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    q[0] = cr * cp * cy + sr * sp * sy
    q[1] = sr * cp * cy - cr * sp * sy
    q[2] = cr * sp * cy + sr * cp * sy
    q[3] = cr * cp * sy - sr * sp * cy


@jit
def quats_to_euler(qs, es):
    """:func:`quat_to_euler` of each row of qs (N, 4), written to es (N, 3)."""
    for i in range(qs.shape[0]):
        quat_to_euler(qs[i], es[i])


@jit
def wrap_pi(a):
    """Angle wrapped into [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _vector(q):
    return np.asarray(q, dtype=np.float64)


def rotation_matrix(q):
    """R(q) (3, 3), body FRD -> NED, of a unit quaternion [w, x, y, z]."""
    R = np.empty((3, 3))
    quat_to_rotmat(_vector(q), R)
    return R


def euler_from_quat(q):
    """ZYX Euler angles [roll, pitch, yaw] of a unit quaternion [w, x, y, z]."""
    e = np.empty(3)
    quat_to_euler(_vector(q), e)
    return e


def quat_from_euler(roll, pitch, yaw):
    """Quaternion [w, x, y, z] of ZYX Euler angles (yaw, then pitch, then roll)."""
    q = np.empty(4)
    euler_to_quat(float(roll), float(pitch), float(yaw), q)
    return q


def level_quat(yaw):
    """The level attitude with heading ``yaw``."""
    return np.array([math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)])
