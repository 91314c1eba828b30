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


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def _quat_rotate(qt: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Rotate points x (..., 3) by the unit quaternion qt (x, y, z, w)."""
    u, w = qt[:3], qt[3]
    return x + 2.0 * np.cross(u, np.cross(u, x) + w * x)


def arc_points(kappa: float, psi: float, length: float, s: np.ndarray) -> np.ndarray:
    """Points (len(s), 3) of a constant-curvature arc in its root frame, bending in the plane
    at angle psi; finite at kappa = 0."""
    ks = kappa * s
    # (1 - cos ks)/kappa and sin(ks)/kappa without dividing by a small kappa
    a = np.where(abs(kappa) > 1e-9, (1.0 - np.cos(ks)) / np.where(kappa == 0, 1, kappa), 0.5 * kappa * s**2)
    b = np.where(abs(kappa) > 1e-9, np.sin(ks) / np.where(kappa == 0, 1, kappa), s)
    return np.stack([a * math.cos(psi), a * math.sin(psi), b], axis=-1)


def arc_tip_quat(kappa: float, psi: float, length: float) -> np.ndarray:
    """Rotation of the arc's tip frame: angle kappa*length about (-sin psi, cos psi, 0)."""
    th = kappa * length
    axis = np.array([-math.sin(psi), math.cos(psi), 0.0])
    return np.r_[math.sin(th / 2) * axis, math.cos(th / 2)]


def arm_record(t: float, step: int, n: int = N_SEGMENTS, P: int = POINTS, freq: float = 1.0) -> StepRecord:
    """The synthetic arm at time t: curvature kappa_i(t) = 12 sin(2 pi f t + i) 1/m."""
    s = np.linspace(0.0, LENGTH, P)
    pos = np.zeros(3)
    quat = np.array([0.0, 0.0, 0.0, 1.0])
    backbone = np.empty((n, P, 3))
    tips = np.empty((n, 7))
    q = np.empty(3 * n)
    v = np.empty(3 * n)
    for i in range(n):
        kappa = 12.0 * math.sin(2 * math.pi * freq * t + i)
        kdot = 12.0 * 2 * math.pi * freq * math.cos(2 * math.pi * freq * t + i)
        psi = 2.0 * math.pi * i / n
        backbone[i] = pos + _quat_rotate(quat, arc_points(kappa, psi, LENGTH, s))
        tip_local = arc_points(kappa, psi, LENGTH, np.array([LENGTH]))[0]
        pos = pos + _quat_rotate(quat, tip_local)
        quat = _quat_mul(quat, arc_tip_quat(kappa, psi, LENGTH))
        tips[i, :3] = pos
        tips[i, 3:] = quat
        q[3 * i : 3 * i + 3] = (LENGTH, kappa * math.cos(psi), kappa * math.sin(psi))
        v[3 * i : 3 * i + 3] = (0.0, kdot * math.cos(psi), kdot * math.sin(psi))
    p = 4.0e4 * (1.0 + np.sin(2 * math.pi * freq * t + np.arange(3 * n)))
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
    print("started", flush=True)
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
