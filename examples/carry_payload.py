"""A three-segment arm hanging from its base lifts a ball at its tip and carries it a third of a
turn round the base.

The scene (``scenes/carry_payload.toml``): the arm hangs along world -z from a base 0.5 m up;
its ``[payload]`` is a 40 g ball of 20 mm radius centred 20 mm beyond the tip (44% of the
arm's 90 g), a rigid body moving with the tip (``Chain(payload=pinocchio.Inertia(...))``),
gravity on it. Chamber 1 of every segment ramps to 200 kPa over 1.5 s: the arm curls
sideways and up and lifts the ball; after a 1 s hold the bending moment turns from chamber 1
to chamber 2 (120 degrees about the arm's axis, the same moment in every direction) over 3 s,
so the raised ball is carried round the vertical through the base; then the pressures are held
and the arm settles. Chambers 2 and 3 differ, so the model is the full one (9 coordinates).

Checked at the end, against statics: the settled state beside ``qchain.equilibrium`` at the
final pressures (Newton from the final state), and that static shape beside the one of the
same arm without the payload carrying the ball's weight as a ``PointLoad`` at its tip instead
(the force ``m g`` at the ball's centre: at the tip, ``m g`` and the moment ``(R c) x m g``,
iterated to the shape it acts on), which does not use the payload's code in the passes.

Writes ``carry_payload.png``: side (x-z) and top (x-y) views of the arm at a few instants with
the ball drawn, the path of the ball's centre, and its height against time beside the
pressures. Prints the lift height, the payload's mass, the peak pressure, the angle carried
round, the checks against statics and the wall-clock time per simulated second.

Run: ``.venv/bin/python examples/carry_payload.py [--duration S] [--out DIR] [--quick] [--scene FILE]``
(``--quick``: the lift and its hold, 2.5 s)
"""

from __future__ import annotations

import _common
import matplotlib.pyplot as plt
import numpy as np

from qchain import Chain, equilibrium
from qchain.contact import Environment, PointLoad

#: end of the lift's hold in the scene (s): the raised state is measured here
LIFTED = 2.5


def payload_centres(chain, traj) -> np.ndarray:
    """World position of the payload's centre of mass at each sample (N, 3), m."""
    c = chain.payload.lever
    return np.array([chain.tip_placement(q, t=t).act(c) for t, q in zip(traj.t, traj.q)])


def weight_as_tip_load(chain, p, q0=None, iterations: int = 50, tol: float = 1e-12):
    """The static shape of ``chain``'s arm without its payload, the payload's weight applied
    instead as a ``PointLoad`` at the tip: force ``m g`` (world) and moment ``(R c) x m g``
    about the tip origin, ``R`` the tip's rotation, ``c`` the lever. The moment depends on the
    shape, so the load is updated from each solution until the shape stops moving (a fixed
    point: there the load is the payload's weight on that shape), from ``q0`` (default: the
    straight arm). Returns ``(q, updates)``."""
    P = chain.payload
    bare = Chain(chain.segments, gravity=chain.gravity, base_placement=chain.base_placement)
    f = P.mass * chain.gravity
    q = bare.neutral() if q0 is None else np.array(q0, dtype=float)
    for k in range(1, iterations + 1):
        arm = chain.tip_placement(q).rotation @ P.lever
        env = Environment([], loads=[PointLoad(chain.n - 1, 1.0, f, np.cross(arm, f))])
        res = equilibrium(bare, p, q0=q, env=env)
        if not res.success:
            raise RuntimeError(f"no static shape with the tip load: {res.message}")
        step = float(np.abs(res.q - q).max())
        q = res.q
        if step < tol:
            return q, k
    raise RuntimeError(f"the tip load's shape did not settle in {iterations} updates (last step {step:.3g})")


def draw_ball(ax, centre, radius, axes):
    from matplotlib.patches import Circle

    ax.add_patch(Circle(centre[list(axes)] * 1e3, radius * 1e3, facecolor="C3", edgecolor="k", alpha=0.5, lw=0.8))


def main(argv=None) -> dict:
    args, sc, model, ch, traj, wall = _common.run(__doc__, "carry_payload", argv, quick=LIFTED)
    P = ch.payload
    if P is None or ch.base != "fixed":
        raise SystemExit(f"{sc.path}: this example lifts a [payload] on an arm with a fixed base")
    T = float(traj.t[-1])
    arm_mass = sum(s.mass for s in ch.segments)
    ball = float(np.sqrt(P.inertia[0, 0] / (0.4 * P.mass))) if P.inertia[0, 0] > 0 else 0.01  # a solid ball's radius
    com = payload_centres(ch, traj)

    # the hanging start: the static shape without pressure
    hang = equilibrium(ch, np.zeros(ch.nu))
    hang_com = ch.tip_placement(hang.q).act(P.lever)
    k_up = int(np.argmin(np.abs(traj.t - min(LIFTED, T))))
    lift = float(com[k_up, 2] - hang_com[2])
    peak = float(np.abs(traj.p).max())
    k_peak, j_peak = np.unravel_index(np.argmax(np.abs(traj.p)), traj.p.shape)
    # the carry: the ball's angle round the vertical through the base, from the raised state on
    base = ch.base_placement.translation
    azimuth = np.degrees(np.unwrap(np.arctan2(com[:, 1] - base[1], com[:, 0] - base[0])))
    carried = float(azimuth[-1] - azimuth[k_up])
    during = com[k_up:, 2]

    # the end against statics: Newton from the final state at the final pressures
    q_end, v_end, p_end = traj.q[-1], traj.v[-1], traj.p[-1]
    eq = equilibrium(ch, p_end, q0=q_end)
    to_static = float(np.linalg.norm(com[-1] - ch.tip_placement(eq.q).act(P.lever)))
    V = ch.tip_velocity(q_end, v_end, "local")  # the tip's twist, tip frame: the ball's centre moves at v + w x c
    speed = float(np.linalg.norm(V[:3] + np.cross(V[3:], P.lever)))
    q_load, updates = weight_as_tip_load(ch, p_end)  # from the straight arm: no use of eq
    load_vs_payload = float(np.linalg.norm(ch.tip_placement(q_load).translation - ch.tip_placement(eq.q).translation))

    print(f"payload: {P.mass * 1e3:g} g ball of {ball * 1e3:.3g} mm radius, {P.mass / arm_mass:.0%} of the "
          f"arm's {arm_mass * 1e3:g} g; peak pressure {peak / 1e3:.4g} kPa (chamber {j_peak % 3 + 1} of segment "
          f"{j_peak // 3} at t = {traj.t[k_peak]:.2f} s)")
    print(f"lift: the ball's centre from z = {hang_com[2] * 1e3:.1f} mm (hanging, static) to "
          f"{com[k_up, 2] * 1e3:.1f} mm at t = {traj.t[k_up]:.2f} s: lifted {lift * 1e3:.1f} mm")
    if T > LIFTED:
        turn = "counter-clockwise" if carried > 0 else "clockwise"
        print(f"carry: {abs(carried):.1f} deg round the vertical through the base ({turn} seen from above), the "
              f"ball's centre between z = {during.min() * 1e3:.1f} and {during.max() * 1e3:.1f} mm on the way")
    print(f"end (t = {T:g} s): the ball moves at {speed * 1e3:.2g} mm/s, its centre {to_static * 1e3:.3g} mm from "
          f"the static shape at these pressures (qchain.equilibrium, {'converged' if eq.success else 'NOT converged'});"
          f" that shape's tip {load_vs_payload:.2g} m from the bare arm's carrying the ball's weight as a tip "
          f"PointLoad ({updates} load updates)")
    print(f"simulated {T:g} s in {wall:.3g} s wall (not counting {traj.meta.get('compile_s', 0.0):.2g} s compiling "
          f"or loading the engine): {wall / T:.3g} s wall per simulated second ({sc.method}, {traj.nfev} right-hand "
          "sides)")

    fig, axs = plt.subplots(1, 3, figsize=(16, 5.5), gridspec_kw={"width_ratios": [1, 1, 1.3]})
    sx, tx, hx = axs
    idx = np.unique(np.r_[_common.snapshot_indices(len(traj.t), 6), k_up])
    cmap = plt.get_cmap("viridis")
    for a, axes in ((sx, (0, 2)), (tx, (0, 1))):
        a.plot(com[:, axes[0]] * 1e3, com[:, axes[1]] * 1e3, color="C3", lw=1, label="path of the ball's centre")
        for n, k in enumerate(idx):
            col = cmap(0.85 * n / max(1, len(idx) - 1))
            _common.draw_arm(a, ch, traj.q[k], traj.t[k], axes=axes, color=col, lw=2.5,
                             label=f"t = {traj.t[k]:.2f} s" if a is sx else None)
            draw_ball(a, com[k], ball, axes)
        a.set_aspect("equal", adjustable="datalim")
        a.grid(alpha=0.3)
    sx.set(xlabel="x (mm)", ylabel="z (mm)", title="side view")
    sx.legend(fontsize=7, loc="lower left")
    tx.plot(base[0] * 1e3, base[1] * 1e3, "k+", ms=10)
    tx.set(xlabel="x (mm)", ylabel="y (mm)", title="top view (+: the base)")
    tx.legend(fontsize=7, loc="lower left")
    hx.plot(traj.t, com[:, 2] * 1e3, color="C3", label="height of the ball's centre")
    hx.axhline(hang_com[2] * 1e3, color="C3", ls=":", lw=1, label="hanging (static, no pressure)")
    hx.set(xlabel="t (s)", ylabel="z (mm)", title=f"lifted {lift * 1e3:.0f} mm, carried {abs(carried):.0f} deg round")
    px = hx.twinx()
    for j, ls in ((0, "--"), (1, "-.")):
        px.plot(traj.t, traj.p[:, j] / 1e3, "k", ls=ls, lw=1, label=f"chamber {j + 1} (every segment)")
    px.set_ylabel("pressure (kPa)")
    hx.legend(fontsize=7, loc="upper left")
    px.legend(fontsize=7, loc="lower right")
    hx.grid(alpha=0.3)
    fig.suptitle(f"{sc.name}: a {P.mass * 1e3:g} g ball on a {arm_mass * 1e3:g} g arm, {sc.method}")
    png = _common.save_figure(fig, args.out, "carry_payload.png", dpi=80)
    return {"trajectory": traj, "png": png, "chain": ch, "scene": sc, "payload_centres": com, "hanging": hang,
            "hanging_centre": hang_com, "lifted_index": k_up, "lift": lift, "peak_pressure": peak,
            "carried_deg": carried, "static": eq, "to_static": to_static, "end_speed": speed,
            "tip_load_shape": q_load, "load_vs_payload": load_vs_payload, "wall_per_second": wall / T}


if __name__ == "__main__":
    main()
