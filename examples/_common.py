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


def parser(doc: str, name: str, scene_flag: bool = True) -> argparse.ArgumentParser:
    """The shared flags; ``doc`` is the example's module docstring; ``scene_flag``: whether
    the example runs a scene file (``--scene``, default ``scenes/<name>.toml``)."""
    p = argparse.ArgumentParser(description=doc.strip().splitlines()[0], prog=f"{name}.py")
    if scene_flag:
        p.add_argument("--scene", type=Path, default=SCENES / f"{name}.toml", metavar="FILE",
                       help=f"scene file (default: examples/scenes/{name}.toml)")
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
