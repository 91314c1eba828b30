"""Synthetic step records for the logging tests and benchmark: an analytically bending arm.

Each segment is a constant-curvature arc of length ``L`` whose curvature varies
sinusoidally in time, bending in a plane at angle ``psi_i`` about its root frame's z axis.
The chain is stacked: each segment's root frame is the previous segment's tip frame.
Everything is closed-form, so the records are cheap and reproducible, and they exercise
every field of :class:`qchain.logging.StepRecord`.
"""

from __future__ import annotations

import math

import numpy as np

from qchain.logging import RunInfo, StepRecord

N_SEGMENTS = 3
LENGTH = 0.1  # m, each segment
RADIUS = 0.015  # m
POINTS = 12  # backbone points a segment


def _rot_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(1.0 + tr)
        return np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    i = int(np.argmax(np.diag(R)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2.0 * math.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
    q = np.empty(4)
    q[i] = 0.25 * s
    q[j] = (R[j, i] + R[i, j]) / s
    q[k] = (R[k, i] + R[i, k]) / s
    q[3] = (R[k, j] - R[j, k]) / s
    return q


def arc_points(kappa: float, psi: float, s: np.ndarray) -> np.ndarray:
    """Points (len(s), 3) of a constant-curvature arc in its root frame (tangent z at the
    root), bending in the plane at angle psi about z; finite at kappa = 0."""
    ks = kappa * s
    if abs(kappa) > 1e-9:
        a = (1.0 - np.cos(ks)) / kappa
        b = np.sin(ks) / kappa
    else:
        a = 0.5 * kappa * s * s
        b = s.copy()
    return np.stack([a * math.cos(psi), a * math.sin(psi), b], axis=-1)


def arc_tip_rotation(kappa: float, psi: float, length: float) -> np.ndarray:
    """Rotation of the arc's tip frame: angle kappa*length about (-sin psi, cos psi, 0)."""
    th = kappa * length
    c, s = math.cos(th), math.sin(th)
    ux, uy = -math.sin(psi), math.cos(psi)
    K = np.array([[0.0, 0.0, uy], [0.0, 0.0, -ux], [-uy, ux, 0.0]])  # [u]x with u = (ux, uy, 0)
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def arm_record(t: float, step: int, n: int = N_SEGMENTS, P: int = POINTS, freq: float = 1.0) -> StepRecord:
    """The synthetic arm at time t: curvature kappa_i(t) = 12 sin(2 pi f t + i) 1/m, bending
    plane at 2 pi i / n; the root frame is the world frame."""
    s = np.linspace(0.0, LENGTH, P)
    pos = np.zeros(3)
    R = np.eye(3)
    backbone = np.empty((n, P, 3))
    tips = np.empty((n, 7))
    q = np.empty(3 * n)
    v = np.empty(3 * n)
    w = 2 * math.pi * freq
    for i in range(n):
        kappa = 12.0 * math.sin(w * t + i)
        kdot = 12.0 * w * math.cos(w * t + i)
        psi = 2.0 * math.pi * i / n
        local = arc_points(kappa, psi, s)
        backbone[i] = pos + local @ R.T
        pos = backbone[i, -1].copy()
        R = R @ arc_tip_rotation(kappa, psi, LENGTH)
        tips[i, :3] = pos
        tips[i, 3:] = _rot_to_quat(R)
        cp, sp = math.cos(psi), math.sin(psi)
        q[3 * i : 3 * i + 3] = (LENGTH, kappa * cp, kappa * sp)
        v[3 * i : 3 * i + 3] = (0.0, kdot * cp, kdot * sp)
    p = 4.0e4 * (1.0 + np.sin(w * t + np.arange(3 * n)))
    kinetic = 0.5 * 1e-4 * float(v @ v)
    potential = 0.5 * 1e-3 * float(q @ q) + 0.01 * float(backbone[:, :, 2].mean())
    return StepRecord(
        t=t, step=step, q=q, v=v, p=p, kinetic=kinetic, potential=potential, total=kinetic + potential,
        backbone=backbone, tip_frames=tips,
    )


def arm_records(n_steps: int, dt: float = 1e-3, **kw) -> list[StepRecord]:
    return [arm_record(k * dt, k, **kw) for k in range(n_steps)]


def arm_info(n: int = N_SEGMENTS, **kw) -> RunInfo:
    kw.setdefault("scene", '[arm]\nsegments = 3\n# a synthetic "scene" with unicode: κ(t)\n')
    kw.setdefault("scene_path", "scenes/synthetic_arm.toml")
    kw.setdefault("params", {"length": LENGTH, "radius": RADIUS, "E": 1.0e5, "gravity": [0.0, 0.0, -9.81]})
    return RunInfo(n_segments=n, radii=[RADIUS] * n, **kw)


DRIVER = r'''
"""Feeds the synthetic arm through RunLogger until told to stop (or killed)."""
import sys, time
sys.path.insert(0, {tests!r})
from logging_fixtures import arm_info, arm_record
from qchain.logging import RunLogger

path, n_max, pace = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
with RunLogger(arm_info(), path, flush_interval={flush!r}) as log:
    print("writer", log.worker_pid, flush=True)
    k = 0
    while k < n_max:
        t = k * 1e-3
        log.log(arm_record(t, k))
        if k % 50 == 0:
            print(f"t {{t!r}}", flush=True)
            time.sleep(pace)
        k += 1
print("done", flush=True)
'''


def write_driver(path, tests_dir, flush: float = 0.1) -> None:
    """Write the driver script (run as: python DRIVER OUT.mcap N_MAX PACE_S)."""
    path.write_text(DRIVER.format(tests=str(tests_dir), flush=flush))
