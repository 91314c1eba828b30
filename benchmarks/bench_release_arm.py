"""The four-segment spatial arm in ``pinocchio.aba`` calls per simulated second (bench_release's arm part).

Scene: ``examples/scenes/spatial_arm.toml`` (four segments hanging, driven in all chambers with
pressures turning round each segment: 12 free coordinates, no reduction applies), its 2 s
(``--quick``: 1 s) sampled at its 50 Hz. Every method of ``qchain.sim.simulation.METHODS``
over bench_precision's ``settings``. Error: the largest tip distance from the converged tip path
(``radau5`` at rtol 1e-10, checked against ``dopri5`` at rtol 1e-10; both cached with
bench_release's ``cached_track``). Cost: CPU seconds (``time.process_time``) of ``simulate`` per
simulated second (energies off, each setting run once untimed first), median of repeats, and the
same cost in calls of ``pinocchio.aba`` on the equal-nv rigid chain (bench_precision's
``aba_call_s`` in CPU time, timed in the same run). Headline: the cheapest run within 1 mm (target:
at most 500 aba calls per simulated second).

Run through ``python benchmarks/bench_release.py`` (``--no-arm`` skips it) or alone:
``python benchmarks/bench_release_arm.py [--quick] [--out DIR]``; writes ``release_arm.csv``.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

import _study
import bench_precision as bp
import bench_release as br

SCENE_FILE = bp.SCENES / "spatial_arm.toml"
REF = ("radau5", 1e-10)
CHECK = ("dopri5", 1e-10)


def run(quick: bool = False, out_dir: Path = Path("out/bench"), cache: Path | None = None,
        T: float | None = None) -> list[dict]:
    """Sweep every method on the arm for ``T`` s (default the scene's duration); print the table and
    the headline; write ``release_arm.csv`` into ``out_dir``; return the rows."""
    from qchain.scene import load_scene
    from qchain.sim.simulation import METHODS, simulate

    sc = load_scene(SCENE_FILE)
    model = sc.build()
    ch = model.chain
    T = float(sc.duration if T is None else T)
    t_eval = sc.sample_times(T)
    clock = br.CLOCK

    def sim(method, **kw):
        return simulate(ch, model.q0, model.v0, (0.0, T), pressure=model.pressure, method=method, t_eval=t_eval,
                        energies=False, **kw)

    def tips(tr):
        return np.array([ch.tip_placement(q).translation for q in tr.q])

    def reference(method, rtol):
        key = dict(code="qchain", scene_file=hashlib.sha1(SCENE_FILE.read_bytes()).hexdigest(), T=T,
                   samples=len(t_eval), method=method, rtol=rtol, atol=rtol * 1e-2, nv=int(ch.nv_active))

        def compute():
            t0 = clock()
            tr = sim(method, rtol=rtol, atol=rtol * 1e-2)
            if not tr.success or len(tr.t) != len(t_eval):
                raise RuntimeError(f"arm reference {method} rtol {rtol:g} failed: {tr.message}")
            return tips(tr), clock() - t0

        x, cpu, hit = br.cached_track(cache, f"arm-{method}", key, compute)
        print(f"arm reference: {method} rtol {rtol:g}: {'cached' if hit else f'{cpu:.1f} s CPU'}", flush=True)
        return x

    print(f"== arm: {sc.name}: {ch.n} segments, {ch.nv_active} free coordinates, {T:g} s", flush=True)
    x_ref = reference(*REF)
    x_check = reference(*CHECK)
    check = float(np.max(np.linalg.norm(x_check - x_ref, axis=1)))
    aba = bp.aba_call_s(ch.n, clock=clock)
    print(f"pinocchio.aba on the rigid chain of nv = {3 * ch.n}: {aba * 1e6:.2f} us CPU a call", flush=True)
    rows = []
    for method in METHODS:
        for kw in bp.settings(method, quick):
            sim(method, **kw)  # compiles or loads the engine, warms the caches
            cpus, tr = [], None
            while len(cpus) < 7 and sum(cpus) < (0.3 if quick else 1.0):
                t0 = clock()
                tr = sim(method, **kw)
                cpus.append(clock() - t0)
            ok = bool(tr.success) and len(tr.t) == len(t_eval)
            err = float(np.max(np.linalg.norm(tips(tr) - x_ref, axis=1))) if ok else float("nan")
            cost = float(np.median(cpus)) / T
            rows.append(dict(scene="spatial_arm", method=method, setting=bp.label(kw), T_s=T, tip_error_m=err,
                             cpu_per_sim_s=cost, aba_calls_per_sim_s=cost / aba, aba_call_s=aba, nfev=tr.nfev,
                             repeats=len(cpus), success=ok, message="" if ok else tr.message))
            print(f"  {method:>9} {bp.label(kw):>12}  err {err:9.2e} m  {cost * 1e3:9.3f} ms/s CPU  "
                  f"{cost / aba:9.0f} aba/s  nfev {tr.nfev:6d}{'' if ok else '  FAILED: ' + tr.message[:70]}",
                  flush=True)
    lines = [f"arm reference: {REF[0]} rtol {REF[1]:g}; {CHECK[0]} rtol {CHECK[1]:g} within {check:.1e} m of it; "
             f"pinocchio.aba {aba * 1e6:.2f} us CPU a call (rigid chain, nv = {3 * ch.n})"]
    for bound in (br.ARM_ACCURACY, br.ARM_ACCURACY / 10):
        best = cheapest_within(rows, bound)
        if best is None:
            lines.append(f"arm headline: no run within {bound * 1e3:g} mm")
            continue
        calls = best["aba_calls_per_sim_s"]
        verdict = (f" (target <= {br.ARM_TARGET:g}: {'met' if calls <= br.ARM_TARGET else 'NOT met'})"
                   if bound == br.ARM_ACCURACY else "")
        lines.append(f"arm headline: cheapest within {bound * 1e3:g} mm (largest tip distance): {best['method']} "
                     f"{best['setting']}: {calls:.0f} pinocchio.aba calls per simulated second{verdict}; "
                     f"{best['cpu_per_sim_s'] * 1e3:.3f} ms CPU per simulated second, "
                     f"error {best['tip_error_m']:.2e} m")
    for line in lines:
        print(line, flush=True)
    _study.write_csv(rows, Path(out_dir) / "release_arm.csv")
    print(f"wrote {Path(out_dir) / 'release_arm.csv'}", flush=True)
    return rows


def cheapest_within(rows: list[dict], bound: float) -> dict | None:
    """The cheapest successful row within ``bound`` m (largest tip distance); None if none."""
    ok = [r for r in rows if r["success"] and r["tip_error_m"] <= bound]
    return min(ok, key=lambda r: r["cpu_per_sim_s"]) if ok else None


def main(argv=None):
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 s and fewer settings")
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for release_arm.csv")
    args = ap.parse_args(argv)
    return run(args.quick, args.out, args.out / "release_cache", T=1.0 if args.quick else None)


if __name__ == "__main__":
    main()
