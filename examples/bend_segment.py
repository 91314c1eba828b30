"""Bend one soft segment with its three chambers and draw the shapes.

For a few pressure sets, solve the static balance of one upright segment under gravity,
``dU_el/dq_e + G_e(q_e) = B(q_e) p``, and plot the backbones (3-D and top view) into
``bend_segment.png``. No scene file: the segment is built in Python (``SEGMENT``).

Run: ``.venv/bin/python examples/bend_segment.py [--out DIR] [--quick]``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.optimize import root  # noqa: E402

import _common  # noqa: E402
from qchain import Segment  # noqa: E402

GRAVITY_ROOT = np.array([0.0, 0.0, -9.81])  # root z axis points up (m/s^2)

SEGMENT = dict(
    length=0.10,  # m
    radius=0.015,  # m
    mass=0.05,  # kg
    chamber_area=4.5e-5,  # m^2 (a 3.8 mm radius chamber)
    chamber_radius=0.0085,  # m
    youngs_modulus=1.0e5,  # Pa (soft silicone)
)

PRESSURE_SETS = {  # Pa, chambers 1..3
    "rest": (0.0, 0.0, 0.0),
    "chamber 1, 40 kPa": (40e3, 0.0, 0.0),
    "chamber 1, 80 kPa": (80e3, 0.0, 0.0),
    "chamber 2, 80 kPa": (0.0, 80e3, 0.0),
    "chambers 2+3, 60 kPa": (0.0, 60e3, 60e3),
    "all, 80 kPa": (80e3, 80e3, 80e3),
}


def static_shape(seg: Segment, p: np.ndarray) -> np.ndarray:
    """Configuration ``q_e`` where elastic, gravity and pressure forces balance."""

    def residual(q):
        return seg.elastic_force(q) + seg.generalized_gravity(q, GRAVITY_ROOT)[6:] - seg.input_matrix(q) @ p

    sol = root(residual, seg.neutral(), tol=1e-12)
    if not sol.success:
        raise RuntimeError(f"no static balance found for p = {p}: {sol.message}")
    return sol.x


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], prog="bend_segment.py")
    parser.add_argument("--out", type=Path, default=Path("out") / "bend_segment", metavar="DIR", help="output folder")
    parser.add_argument("--quick", action="store_true", help="three pressure sets (tests, first look)")
    args = parser.parse_args(argv)

    seg = Segment(**SEGMENT)
    alpha = np.linspace(0.0, 1.0, 41)
    sets = dict(list(PRESSURE_SETS.items())[::2]) if args.quick else PRESSURE_SETS
    shapes = {}
    fig = plt.figure(figsize=(11, 5))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    print(f"{'pressures (kPa)':>24}  {'l (mm)':>7} {'bend (deg)':>10} {'azimuth (deg)':>13}  tip (mm)")
    for label, p in sets.items():
        q = static_shape(seg, np.array(p))
        shapes[label] = q
        pts = seg.backbone(q, alpha) * 1e3
        tip = seg.tip_placement(q).translation * 1e3
        l, ux, uy = q
        kappa = np.hypot(ux, uy)
        azimuth = f"{np.degrees(np.arctan2(uy, ux)):13.1f}" if kappa * l > 1e-9 else f"{'-':>13}"
        print(
            f"{label:>24}  {l * 1e3:7.2f} {np.degrees(kappa * l):10.2f} {azimuth}"
            f"  ({tip[0]:6.2f}, {tip[1]:6.2f}, {tip[2]:6.2f})"
        )
        (line,) = ax3.plot(pts[:, 0], pts[:, 1], pts[:, 2], lw=3, label=label)
        ax2.plot(pts[:, 0], pts[:, 1], lw=3, color=line.get_color())
        ax2.plot(*tip[:2], "o", color=line.get_color())
    for phi in (0.0, 2 * np.pi / 3, -2 * np.pi / 3):
        c = seg.chamber_radius * 1e3 * np.array([np.cos(phi), np.sin(phi)])
        ax2.add_patch(plt.Circle(c, np.sqrt(seg.chamber_area / np.pi) * 1e3, fill=False, ls="--"))
    ax2.add_patch(plt.Circle((0, 0), seg.radius * 1e3, fill=False))
    ax3.set_box_aspect(np.ptp(np.array([ax3.get_xlim3d(), ax3.get_ylim3d(), ax3.get_zlim3d()]), axis=1))
    ax3.set_xlabel("x (mm)")
    ax3.set_ylabel("y (mm)")
    ax3.set_zlabel("z (mm)")
    ax3.set_title("backbone under chamber pressures and gravity")
    ax3.legend(fontsize=7, loc="upper left")
    ax2.set_aspect("equal")
    ax2.set_xlabel("x (mm)")
    ax2.set_ylabel("y (mm)")
    ax2.set_title("top view (dashed: chambers 1-3 at 0, 120, -120 deg)")
    png = _common.save_figure(fig, args.out, "bend_segment.png", dpi=120)
    return {"png": png, "shapes": shapes}


if __name__ == "__main__":
    main()
