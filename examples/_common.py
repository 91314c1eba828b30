"""Shared pieces of the example scripts: their flags, their scene files, their figures.

Every example takes ``--duration S`` (simulated time instead of the scene's), ``--out DIR``
(output folder, default ``out/<example>``), ``--quick`` (a short run for tests and a first
look) and ``--scene FILE`` (another scene file in place of ``scenes/<example>.toml``, e.g. a
copy with other segments: the script's analysis assumes the kind of arm its own scene has).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402

from qchain import Scene, load_scene  # noqa: E402

SCENES = Path(__file__).resolve().parent / "scenes"


def parser(doc: str, name: str, scene_flag: bool = True, scene: str | None = None) -> argparse.ArgumentParser:
    """The shared flags; ``doc`` is the example's module docstring; ``scene_flag``: whether
    the example runs a scene file (``--scene``, default ``scenes/<scene>.toml``, ``scene``
    defaulting to ``name``: examples that drive the same arm share its file)."""
    p = argparse.ArgumentParser(description=doc.strip().splitlines()[0], prog=f"{name}.py")
    if scene_flag:
        scene = scene or name
        p.add_argument("--scene", type=Path, default=SCENES / f"{scene}.toml", metavar="FILE",
                       help=f"scene file (default: examples/scenes/{scene}.toml)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="simulated time (s); default the scene's")
    p.add_argument("--out", type=Path, default=Path("out") / name, metavar="DIR", help="output folder")
    p.add_argument("--quick", action="store_true", help="a short run (tests, first look)")
    return p


def scene(name: str, args=None) -> Scene:
    """The example's scene: ``args.scene`` (``--scene``) if given, else the file
    ``examples/scenes/<name>.toml``."""
    path = getattr(args, "scene", None) or SCENES / f"{name}.toml"
    return load_scene(path)


def duration(args, sc: Scene, quick: float) -> float:
    """``--duration``, else ``quick`` seconds with ``--quick``, else the scene's."""
    if args.duration is not None:
        if not args.duration > 0:
            raise SystemExit(f"--duration must be > 0 s, got {args.duration}")
        return args.duration
    return min(quick, sc.duration) if args.quick else sc.duration


def tips(chain, traj) -> np.ndarray:
    """World tip positions (N, 3), m."""
    return np.array([chain.tip_placement(q, t=t).translation for t, q in zip(traj.t, traj.q)])


def snapshot_indices(N: int, k: int) -> np.ndarray:
    return np.unique(np.linspace(0, N - 1, min(k, N)).round().astype(int))


def draw_arm(ax, chain, q, t, axes=(0, 2), color="C0", lw=3.0, label=None):
    """Draw the backbone at (q, t) in the plane of world ``axes`` (mm)."""
    pts = chain.backbone(q, 16, t=t).reshape(-1, 3) * 1e3
    ax.plot(pts[:, axes[0]], pts[:, axes[1]], color=color, lw=lw, label=label, solid_capstyle="round")
    ax.plot(pts[0, axes[0]], pts[0, axes[1]], "ks", ms=4)
    return pts


def run(doc: str, name: str, argv, quick: float):
    """Parse the shared flags, build the scene's model, print it, run it and report.

    Returns ``(args, scene, model, chain, traj, wall)`` with ``wall`` the run's wall time (s).
    """
    import time

    args = parser(doc, name).parse_args(argv)
    sc = scene(name, args)
    model = sc.build()
    T = duration(args, sc, quick=quick)
    print("\n".join(sc.describe(model)))
    t0 = time.perf_counter()
    traj = sc.simulate(model=model, duration=T)
    wall = time.perf_counter() - t0 - traj.meta.get("compile_s", 0.0)  # the run, without a first compile
    report(traj)
    return args, sc, model, model.chain, traj, wall


def report(traj) -> None:
    print(f"run: {'success' if traj.success else 'FAILED'}: {traj.message} (nfev = {traj.nfev})")


def draw_obstacle(ax, ob, axes=(0, 2), color="0.6", height=None):
    """Draw a contact obstacle (``qchain.contact``) in the plane of world ``axes`` (mm): a
    half-space as its boundary line (hatched on the solid's side), a cylinder or capsule whose
    axis is along a world axis as a disc (seen along its axis) or a rectangle (a capsule's
    rounded ends drawn square). ``height`` (m): the half-space's line runs this far either side
    of its ``point`` (default 0.5 m)."""
    from matplotlib.patches import Circle, Rectangle

    from qchain.contact import Capsule, Cylinder, HalfSpace

    i, j = axes
    if isinstance(ob, HalfSpace):
        n = ob.normal[[i, j]]
        t = np.array([-n[1], n[0]])
        L = 0.5 if height is None else height
        ends = np.array([ob.point[[i, j]] - L * t, ob.point[[i, j]] + L * t]) * 1e3
        ax.plot(ends[:, 0], ends[:, 1], color=color, lw=2)
        for s in np.linspace(-1, 1, 41):  # hatching on the solid's side
            a = (ob.point[[i, j]] + s * L * t) * 1e3
            b = a - 4.0 * (n + t) / np.sqrt(2)
            ax.plot([a[0], b[0]], [a[1], b[1]], color=color, lw=0.7)
    elif isinstance(ob, (Cylinder, Capsule)):
        u = ob.b - ob.a
        if np.count_nonzero(np.abs(u) > 1e-12) != 1:
            raise ValueError("draw_obstacle draws a cylinder or capsule whose axis is along a world axis")
        if abs(u[i]) < 1e-12 and abs(u[j]) < 1e-12:  # seen along its axis: a disc
            ax.add_patch(Circle(ob.a[[i, j]] * 1e3, ob.radius * 1e3, color=color, alpha=0.6))
        else:  # an axis along one of the drawing's axes: a rectangle
            lo = np.minimum(ob.a, ob.b)[[i, j]] - ob.radius * (np.abs(u[[i, j]]) < 1e-12)
            hi = np.maximum(ob.a, ob.b)[[i, j]] + ob.radius * (np.abs(u[[i, j]]) < 1e-12)
            ax.add_patch(Rectangle(lo * 1e3, *(hi - lo) * 1e3, color=color, alpha=0.6))
    else:
        raise TypeError(f"draw_obstacle draws HalfSpace, Cylinder and Capsule, got {type(ob).__name__}")


def draw_contacts(ax, contacts, axes=(0, 2), mm_per_newton=20.0, color="C3"):
    """Draw contact points (dots) and the forces on the arm (arrows, ``mm_per_newton``) of a
    :class:`qchain.contact.Contacts` in the plane of world ``axes`` (mm)."""
    if len(contacts.segment) == 0:
        return
    i, j = axes
    pt = contacts.point * 1e3
    f = contacts.force * mm_per_newton
    ax.plot(pt[:, i], pt[:, j], ".", color=color, ms=3)
    ax.quiver(pt[:, i], pt[:, j], f[:, i], f[:, j], color=color, angles="xy", scale_units="xy", scale=1.0,
              width=0.004)


def save_figure(fig, out, filename: str, dpi: int = 110):
    """Lay ``fig`` out, write it as ``out / filename`` (the folder made if needed), close it and
    say so; returns the path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / filename
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    print(f"wrote {path}")
    return path
