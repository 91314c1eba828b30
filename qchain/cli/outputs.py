"""What ``qchain run`` writes and prints: the plots and ``trajectory.npz`` of a scene's
``[output]``, and the run summary."""

from __future__ import annotations

import math
import sys
from contextlib import suppress
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import OutputError

if TYPE_CHECKING:
    import numpy as np

    from ..scene.scene import Scene, SceneModel

# --------------------------------------------------------------------------------------
# outputs


def tip_positions(model: SceneModel, traj) -> np.ndarray:
    """World tip positions (N, 3) m of a trajectory."""
    import numpy as np

    ch = model.chain
    return np.array([ch.tip_placement(q, t=t).translation for t, q in zip(traj.t, traj.q)])


def planned_outputs(scene: Scene, folder: Path | None = None) -> list[Path]:
    """The files :func:`write_outputs` will write for ``scene`` into ``folder`` (default the
    scene's ``output.folder``): its plots (``NAME.png``; ``momentum.png`` for a floating base
    only; ``tension.png`` beside ``pressure.png`` for a scene with tendons) and
    ``trajectory.npz`` if ``output.save``. Checked before the run."""
    folder = Path(scene.output_folder if folder is None else folder)
    floating = getattr(getattr(scene, "base", None), "type", None) == "floating"
    names = [f"{name}.png" for name in scene.plots if name != "momentum" or floating]
    if "pressure" in scene.plots and getattr(scene, "tendons", ()):
        names.append("tension.png")
    if scene.save:
        names.append("trajectory.npz")
    return [folder / name for name in names]


def write_outputs(scene: Scene, model: SceneModel, traj, folder: Path, plots=None, save: bool | None = None) -> list[Path]:
    """Write the plots (PNG, ``plots`` default the scene's; the ``pressure`` plot adds
    ``tension.png`` when the trajectory has tensions) and ``trajectory.npz`` (``save`` default
    the scene's: t, q, v, p, energies, tip, success, message, and ``tension`` (N, nt) N with
    tendons) into ``folder``; return the paths."""
    import os
    import secrets

    import numpy as np

    plots = scene.plots if plots is None else tuple(plots)
    save = scene.save if save is None else save
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    failed: list[str] = []
    t = traj.t
    tip = tip_positions(model, traj) if len(t) else np.zeros((0, 3))
    if save:  # the data first (the plots may fail), whole or not at all: a temporary file renamed
        path = folder / "trajectory.npz"
        tmp = folder / f".trajectory-{os.getpid()}-{secrets.token_hex(4)}.npz"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask's mode, as a plain open
            extra = {} if getattr(traj, "tension", None) is None else {"tension": traj.tension}
            with os.fdopen(fd, "wb") as fh:
                np.savez_compressed(fh, t=t, q=traj.q, v=traj.v, p=traj.p, kinetic_energy=traj.kinetic_energy,
                                    potential_energy=traj.potential_energy, tip=tip, success=traj.success,
                                    message=traj.message, **extra)
            os.replace(tmp, path)
            written.append(path)
        except OSError as exc:
            failed.append(f"{path} ({exc.strerror or exc})")
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    if not plots:
        _raise_failed(failed, written)
        return written
    if "matplotlib" not in sys.modules:  # Agg is chosen below: a bad MPLBACKEND in the environment is moot
        os.environ.pop("MPLBACKEND", None)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # the scene's name as plain text: '$' would start matplotlib's mathtext (and "$x^$" fail)
    title = (scene.name or (scene.path.stem if scene.path else "scene")).replace("$", r"\$")

    def finish(fig, name, ax=None, ylabel="", what="", **legend):
        if ax is not None:  # a plot over time: its labels, legend and grid
            ax.set_xlabel("t (s)")
            ax.set_ylabel(ylabel)
            ax.set_title(f"{title}: {what}")
            ax.legend(**legend)
            ax.grid(alpha=0.3)
        path = folder / name
        try:
            fig.tight_layout()
            fig.savefig(path, dpi=110)
            written.append(path)
        except (OSError, ValueError, RuntimeError) as exc:  # a full disk, a file size limit, a renderer's error
            failed.append(f"{path} ({getattr(exc, 'strerror', None) or f'{type(exc).__name__}: {exc}'})")
            with suppress(OSError):
                os.unlink(path)  # no half-written PNG left behind
        finally:
            plt.close(fig)

    if "tip" in plots:
        fig, ax = plt.subplots(figsize=(8, 4))
        for k, c in enumerate("xyz"):
            ax.plot(t, tip[:, k] * 1e3, label=c)
        finish(fig, "tip.png", ax, "tip position, world (mm)", "tip position")
    if "arm" in plots:
        fig = plot_arm(model, traj, tip, title, env=scene.environment)
        finish(fig, "arm.png")
    if "energy" in plots:
        fig, ax = plt.subplots(figsize=(8, 4))
        ax.plot(t, traj.kinetic_energy, label="kinetic")
        ax.plot(t, traj.potential_energy, label="potential (gravity + elastic)")
        ax.plot(t, traj.total_energy, "k", label="total")
        finish(fig, "energy.png", ax, "energy (J)", "energies")
    if "pressure" in plots:
        fig, ax = plt.subplots(figsize=(8, 4))
        for k in range(traj.p.shape[1]):
            ax.plot(t, traj.p[:, k] / 1e3, label=f"segment {k // 3}, chamber {k % 3 + 1}")
        finish(fig, "pressure.png", ax, "pressure (kPa)", "chamber pressures", fontsize=7, ncol=3)
        if getattr(traj, "tension", None) is not None:  # the tendons' inputs, beside the chambers'
            fig, ax = plt.subplots(figsize=(8, 4))
            for k in range(traj.tension.shape[1]):
                ax.plot(t, traj.tension[:, k], label=f"tendon {k}")
            finish(fig, "tension.png", ax, "tension (N)", "tendon tensions")
    if "momentum" in plots and model.chain.floating and len(t):
        h = momenta(model, traj)
        fig, ax = plt.subplots(figsize=(8, 4))
        for k, name in enumerate(["px", "py", "pz", "Lx", "Ly", "Lz"]):
            ax.plot(t, h[:, k] - h[0, k], label=name)
        finish(fig, "momentum.png", ax, "momentum drift h(t) - h(0) (kg m/s, kg m^2/s)",
               f"world momentum drift (max {np.abs(h - h[0]).max():.2e})", ncol=2)
    _raise_failed(failed, written)
    return written


def _raise_failed(failed: list[str], written: list) -> None:
    if failed:
        raise OutputError(f"could not write {'; '.join(failed)}", written)


def momenta(model: SceneModel, traj) -> np.ndarray:
    """World momentum (N, 6) of a trajectory: linear (kg m/s), angular about the origin (kg m^2/s)."""
    import numpy as np

    ch = model.chain
    return np.array([ch.momentum(q, v, t=t) for t, q, v in zip(traj.t, traj.q, traj.v)])


def plot_arm(model: SceneModel, traj, tip: np.ndarray, title: str, snapshots: int = 8, env=None):
    """Side (x-z) and top (x-y) views of the arm at ``snapshots`` times, with the tip path and
    the obstacles of ``env`` (a :class:`qchain.contact.Environment`) as seen in each view."""
    import matplotlib.pyplot as plt
    import numpy as np

    ch = model.chain
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    N = len(traj.t)
    idx = np.unique(np.linspace(0, N - 1, min(snapshots, N)).round().astype(int)) if N else []
    cmap = plt.get_cmap("viridis")
    for (a, b), ax, view in (((0, 2), axes[0], "side view (x-z)"), ((0, 1), axes[1], "top view (x-y)")):
        ax.plot(tip[:, a] * 1e3, tip[:, b] * 1e3, color="0.6", lw=1, label="tip path")
        for n_, k in enumerate(idx):
            pts = ch.backbone(traj.q[k], 16, t=traj.t[k]).reshape(-1, 3) * 1e3
            c = cmap(n_ / max(1, len(idx) - 1))
            ax.plot(pts[:, a], pts[:, b], color=c, lw=3, label=f"t = {traj.t[k]:.2f} s")
            ax.plot(pts[0, a], pts[0, b], "ks", ms=4)
        ax.set_aspect("equal", adjustable="datalim")
        if env is not None:
            _draw_obstacles(ax, env.obstacles, a, b)
        ax.set_xlabel(f"{'xyz'[a]} (mm)")
        ax.set_ylabel(f"{'xyz'[b]} (mm)")
        ax.set_title(view)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{title}: arm snapshots")
    return fig


def _draw_obstacles(ax, obstacles, a: int, b: int) -> None:
    """The obstacles projected on the view of world axes ``a``, ``b`` (mm), in grey: a
    half-space as its boundary line (none when the view looks along its normal), the other
    shapes as the outline of their projection."""
    import numpy as np
    from matplotlib.patches import Circle, Polygon
    from scipy.spatial import ConvexHull, QhullError

    from ..contact.shapes import Box, Capsule, HalfSpace, Sphere

    style = dict(facecolor="0.85", edgecolor="0.4", alpha=0.6, zorder=0)
    circle = np.stack([np.cos(np.linspace(0, 2 * np.pi, 24)), np.sin(np.linspace(0, 2 * np.pi, 24))], 1)
    for ob in obstacles:
        if isinstance(ob, HalfSpace):
            n = ob.normal[[a, b]]
            if np.hypot(*n) > 1e-9:  # the boundary is a line in this view
                p = ob.point[[a, b]] * 1e3
                ax.axline(p, p + np.array([-n[1], n[0]]), color="0.4", lw=1.5, zorder=0)
        elif isinstance(ob, Sphere):
            ax.add_patch(Circle(ob.center[[a, b]] * 1e3, ob.radius * 1e3, **style))
        else:  # capsule, cylinder (their ends' discs or balls), box (its corners): the hull of the projection
            if isinstance(ob, Box):
                signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
                pts = ob.center + (signs * ob.half_extents) @ ob.rotation.T
            elif isinstance(ob, Capsule):  # balls at the ends
                pts = np.concatenate([end + ob.radius * np.insert(circle, k, 0.0, axis=1)
                                      for end in (ob.a, ob.b) for k in range(3)])
            else:  # a cylinder: discs normal to its axis at the ends
                axis = (ob.b - ob.a) / np.linalg.norm(ob.b - ob.a)
                u = np.cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
                u /= np.linalg.norm(u)
                rim = ob.radius * (circle[:, :1] * u + circle[:, 1:] * np.cross(axis, u))
                pts = np.concatenate([ob.a + rim, ob.b + rim])
            xy = pts[:, [a, b]] * 1e3
            try:
                ax.add_patch(Polygon(xy[ConvexHull(xy).vertices], **style))
            except QhullError:  # a flat projection (no area): its extent as a line
                ax.plot(xy[:, 0], xy[:, 1], color="0.4", lw=1.5, zorder=0)


# --------------------------------------------------------------------------------------
# summary


#: the most values a summary line lists one by one (a longer list is summed up)
SUMMARY_LIST = 12


def _values(x) -> str:
    """Values a segment, listed (``0.1, 0.2``), or for more than :data:`SUMMARY_LIST` segments
    summed up: the largest, which segment, the median and the smallest."""
    import numpy as np

    x = np.asarray(x, dtype=float)
    if x.size <= SUMMARY_LIST:
        return ", ".join(f"{v:.3g}" for v in x)
    j = int(np.argmax(x))
    return (f"{x.size} segments, largest {x[j]:.3g} (segment {j}), median {float(np.median(x)):.3g}, smallest "
            f"{float(np.min(x)):.3g}")


def summary_lines(scene: Scene, model: SceneModel, traj, wall: float, message: str | None = None) -> list[str]:
    """The run summary ``qchain run`` prints; ``wall`` s excludes compiling; ``message``, how the
    run ended instead of ``traj.message`` (an interrupt), makes it no success."""
    import numpy as np
    import pinocchio as pin

    ok = traj.success and message is None
    lines = [f"run: {'success' if ok else 'FAILED'}: {traj.message if message is None else message}"]
    if len(traj.t) == 0:
        return lines + ["no samples were recorded"]
    t_end = float(traj.t[-1])
    rtf = t_end / wall if wall > 0 else math.inf
    lines.append(f"simulated {t_end:.6g} s in {wall:.3g} s wall time: {rtf:.3g} x real time; nfev = {traj.nfev}, "
                 f"{len(traj.t)} samples, method {scene.method} ({traj.meta.get('engine', 'python')} engine)")
    if traj.meta.get("compile_s", 0.0) > 0.05:
        lines.append(f"  compiled or loaded the engine first in {traj.meta['compile_s']:.3g} s (not in the wall time)")
    X = model.chain.tip_placement(traj.q[-1], t=t_end)
    p = X.translation * 1e3
    rpy = np.degrees(pin.rpy.matrixToRpy(X.rotation))
    quat = pin.Quaternion(X.rotation).coeffs()  # x, y, z, w
    lines.append(f"final tip (t = {t_end:.6g} s, world): position ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) mm")
    lines.append(f"  orientation rpy ({rpy[0]:.3f}, {rpy[1]:.3f}, {rpy[2]:.3f}) deg, quaternion xyzw "
                 f"({quat[0]:.6f}, {quat[1]:.6f}, {quat[2]:.6f}, {quat[3]:.6f})")
    reached = scene.bends(model.chain, traj)
    line = f"largest bends reached (rad): {_values(reached)}"
    warning = None
    if model.max_bend is not None:
        sized = sorted({float(f"{x:.3g}") for x in model.max_bend})
        line += f"; nodes sized for {_values(sized)}"
        over = np.flatnonzero(reached > model.max_bend)
        if over.size:
            j = int(over[0])
            warning = (f"warning: segment {j} bent {reached[j]:.3g} rad, more than the {model.max_bend[j]:.3g} rad its "
                       f"{model.nodes[j]} nodes were sized for: set model.max_bend in the scene")
    lines.append(line)
    if warning is not None:
        lines.append(warning)
    ke, pe = traj.kinetic_energy, traj.potential_energy
    if traj.meta.get("contact_time_scale") is not None:  # a run with obstacles (qchain.sim.simulation)
        limited = traj.meta.get("step_limited_by_contact", False)
        lines.append(f"contact: time scale {traj.meta['contact_time_scale'] * 1e3:.3g} ms; the steps were "
                     + ("limited by it (in contact, the mean step was under a quarter of it)" if limited else
                        "not limited by it"))
    lines.append(f"energies (J): kinetic {ke[-1]:.6g}, potential {pe[-1]:.6g} (gravity + elastic), total "
                 f"{ke[-1] + pe[-1]:.6g}; at the start total {ke[0] + pe[0]:.6g}")
    return lines
