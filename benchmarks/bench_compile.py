"""Cold compile and warm cache-load time of the numba kernels a simulation uses.

The first run after an install compiles every kernel (``cache=True``); later runs load them
from numba's cache. This measures both, each in a fresh interpreter:

* **cold**: a subprocess with ``NUMBA_CACHE_DIR`` set to an empty temporary directory (numba
  0.68's ``UserProvidedCacheLocator`` comes first among its cache locators, so the cache is
  written and read there, not in ``qchain/__pycache__``; the script checks it: the kernels'
  cache path is in the directory, the index files went there and the warm run below compiled
  nothing), which imports qchain and times the first call of each step below, wall and CPU
  time (the compile is single-threaded: CPU time is its cost on an idle core, wall time grows
  with the load of a shared machine);
* **warm**: a second subprocess sharing that cache directory, the same steps: the time is
  the cache load (and one call).

Steps (a 3-segment chain of ``tests/test_chain.make_chain``: curvature coordinates, fixed
base, one paper-actuated segment), in the order an engine would meet them:

``fd_unchecked``  ``forward_dynamics(q, v, p, data=d, skip_checks=True)``: ``internal_forces``,
                  ``aba``, the workspace allocators;
``fdd_unchecked`` ``forward_dynamics_derivatives(q, v, p, data=d, skip_checks=True)``:
                  ``aba_derivatives`` and its callees;
``fd_checked``    ``forward_dynamics(q, v, p, data=d)`` (what ``simulate`` calls): ``first_invalid``
                  and the checked path's argument types;
``fdd_checked``   ``forward_dynamics_derivatives(q, v, p, data=d)``;
``mass_matrix``   ``crba`` (the implicit solvers' Newton matrix);
``inverse_dyn``   ``inverse_dynamics``: ``rnea``;
``frames_batch``  ``frames_batch`` (the recorder) and ``tip_placement`` (the examples).

Printed: the per-step table (cold s, warm s, totals); per top-level kernel the cold compile
(its own compile with every callee compiled for it, from numba's ``numba:compile`` events)
and the warm cache load (``Cache.load_overload``); per compiled function (``jit`` dispatchers,
``register_jitable`` helpers and numba's own overloads alike) its number of specialisations
(compiles), their exclusive compile time (nested compiles taken off) and the part of it in
LLVM (numba's LLVM lock: optimisation and machine code of the function's library, which holds
a copy of every callee), with the duplicated ones listed with their argument types
(``--signatures``: every ``dispatcher.signatures``).

``--example`` also times the README's first command, ``examples/wave_arm.py`` (import, scene
build, the simulation of the scene with its own method, figure), as a whole command in a fresh
interpreter: cold (empty cache) and warm (the cache it wrote), each once plain (the command's
wall time) and once instrumented (numba cache loads: count and time; compiles; the import of
qchain).

Run: ``python benchmarks/bench_compile.py [--repeat 2] [--json out.json] [--signatures] [--example]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
MODULES = ("qchain.model.arc", "qchain.model.slices", "qchain.algorithms.recursive", "qchain.algorithms.rnea_derivatives",
           "qchain.algorithms.aba_derivatives")


# ----------------------------------------------------------------------------- worker


def _worker(out_path: str) -> None:
    t_start = time.perf_counter()
    from numba.core import caching, event

    loads = []  # (qualname, seconds, hit)
    _orig_load = caching.Cache.load_overload

    def timed_load(self, sig, target_context):
        t0 = time.perf_counter()
        cres = _orig_load(self, sig, target_context)
        loads.append((self._py_func.__qualname__, self._py_func.__module__, time.perf_counter() - t0,
                      cres is not None))
        return cres

    caching.Cache.load_overload = timed_load
    rec = event.RecordingListener()
    event.register("numba:compile", rec)
    event.register("numba:llvm_lock", rec)

    t0 = time.perf_counter()
    import numpy as np

    import qchain  # noqa: F401
    from qchain import Chain, Segment

    t_import = time.perf_counter() - t0

    kw = dict(length=0.2, radius=0.02, mass=0.3, chamber_area=2e-5, chamber_radius=0.01, youngs_modulus=1e5)
    segs = [Segment(**{**kw, "length": 0.2 - 0.02 * j, "radius": 0.02 - 0.002 * j, "mass": 0.3 - 0.05 * j},
                    coords="curvature", actuation="paper" if j == 2 else "volume", damping=0.01 * j)
            for j in range(3)]
    ch = Chain(segs, base="fixed")
    d = ch.create_data()
    rng = np.random.default_rng(0)
    q = ch.neutral()
    for j, s in enumerate(ch.segments):
        q[ch.q_slice(j)] = [s.length * rng.uniform(0.9, 1.1), *rng.uniform(-6, 6, 2)]
    v = rng.normal(size=ch.nv)
    v[0::3] *= 0.05
    p = rng.uniform(0, 2e4, ch.nu)
    Q = np.stack([q, q, q])

    steps = {
        "fd_unchecked": lambda: ch.forward_dynamics(q, v, p, data=d, skip_checks=True),
        "fdd_unchecked": lambda: ch.forward_dynamics_derivatives(q, v, p, data=d, skip_checks=True),
        "fd_checked": lambda: ch.forward_dynamics(q, v, p, data=d),
        "fdd_checked": lambda: ch.forward_dynamics_derivatives(q, v, p, data=d),
        "mass_matrix": lambda: ch.mass_matrix(q),
        "inverse_dyn": lambda: ch.inverse_dynamics(q, v, np.zeros(ch.nv)),
        "frames_batch": lambda: (ch.frames_batch(Q, 8), ch.tip_placement(q)),
    }
    times = {}
    cpu = {}
    step_of_event = ["-"] * len(rec.buffer)
    for name, f in steps.items():
        n0 = len(rec.buffer)
        t0 = time.perf_counter()
        c0 = time.process_time()
        f()
        times[name] = time.perf_counter() - t0
        cpu[name] = time.process_time() - c0
        step_of_event += [name] * (len(rec.buffer) - n0)
    # a second call of each: the steady cost (to tell compile/load from running)
    again = {}
    for name, f in steps.items():
        t0 = time.perf_counter()
        f()
        again[name] = time.perf_counter() - t0

    # compile events -> inclusive and exclusive time per (dispatcher, signature), and the
    # time in LLVM (optimisation and machine code, under numba's LLVM lock) of each
    stack = []
    compiles = []
    llvm_depth, llvm_t0 = 0, 0.0
    for (ts, ev), step in zip(rec.buffer, step_of_event):
        if ev.kind == "numba:llvm_lock":
            if ev.status == event.EventStatus.START:
                llvm_depth += 1
                if llvm_depth == 1:
                    llvm_t0 = ts
            else:
                llvm_depth -= 1
                if llvm_depth == 0 and stack:
                    stack[-1][5] += ts - llvm_t0
            continue
        disp = ev.data["dispatcher"]
        key = (disp.py_func.__module__, disp.py_func.__qualname__, str(ev.data["args"]))
        if ev.status == event.EventStatus.START:
            stack.append([key, ts, 0.0, len(stack), step, 0.0])
        else:
            k, t_beg, child, depth, st, llvm = stack.pop()
            assert k == key
            incl = ts - t_beg
            if stack:
                stack[-1][2] += incl
            compiles.append(dict(module=k[0], name=k[1], args=k[2], inclusive=incl, exclusive=incl - child,
                                 llvm=llvm, depth=depth, step=st))

    import numba

    sigs = {}
    for modname in MODULES:
        mod = sys.modules[modname]
        for attr, obj in vars(mod).items():
            if isinstance(obj, numba.core.registry.CPUDispatcher) and obj.py_func.__module__ == modname:
                sigs[f"{modname}.{attr}"] = [str(s) for s in obj.signatures]
    import qchain.algorithms.recursive as rec_mod

    cache_path = rec_mod.aba._cache._cache_path
    json.dump(dict(cache_path=cache_path, import_s=t_import, total_s=time.perf_counter() - t_start, steps=times,
                   cpu=cpu, again=again, compiles=compiles, loads=loads, signatures=sigs), open(out_path, "w"))


def _example_worker(out_path: str, script: str, *argv: str) -> None:
    """Run ``script`` as ``__main__`` with numba's cache loads and compiles timed."""
    t_start = time.perf_counter()
    import runpy

    from numba.core import caching, event

    loads = []
    _orig_load = caching.Cache.load_overload

    def timed_load(self, sig, target_context):
        t0 = time.perf_counter()
        cres = _orig_load(self, sig, target_context)
        loads.append((self._py_func.__module__ + "." + self._py_func.__qualname__, time.perf_counter() - t0,
                      cres is not None))
        return cres

    caching.Cache.load_overload = timed_load
    compiles = []  # outermost compiles: (name, s), their time includes the nested ones
    every = {}  # every compiled function: exclusive s (its nested compiles taken off)
    stack = []

    class Rec(event.Listener):
        def on_start(self, ev):
            stack.append([time.perf_counter(), 0.0])

        def on_end(self, ev):
            t0, child = stack.pop()
            incl = time.perf_counter() - t0
            d = ev.data["dispatcher"].py_func
            name = d.__module__ + "." + d.__qualname__
            every[name] = every.get(name, 0.0) + incl - child
            if stack:
                stack[-1][1] += incl
            else:
                compiles.append((name, incl))

    event.register("numba:compile", Rec())
    t0 = time.perf_counter()
    import qchain  # noqa: F401

    t_import = time.perf_counter() - t0
    sys.argv = [script, *argv]
    sys.path.insert(0, os.path.dirname(os.path.abspath(script)))  # as `python script` has it
    runpy.run_path(script, run_name="__main__")
    json.dump(dict(import_s=t_import, total_s=time.perf_counter() - t_start, loads=loads, compiles=compiles,
                   every=every), open(out_path, "w"))


def measure_example() -> dict:
    """``examples/wave_arm.py`` cold and warm in fresh interpreters sharing an empty cache."""
    script = str(ROOT / "examples" / "wave_arm.py")
    res = {}
    with tempfile.TemporaryDirectory(prefix="qchain-numba-cache-") as cache, \
            tempfile.TemporaryDirectory(prefix="qchain-example-out-") as out:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
        for phase in ("cold", "warm", "warm2"):
            if phase != "warm2":  # plain: the command as a user runs it
                t0 = time.perf_counter()
                p = subprocess.run([sys.executable, script, "--out", out], env=env, cwd=str(ROOT),
                                   capture_output=True, text=True, check=True)
                res[phase + "_plain_s"] = time.perf_counter() - t0
                res[phase + "_stdout"] = p.stdout
                if phase == "cold":
                    continue  # the instrumented runs below are warm
            with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as fh:
                jpath = fh.name
            t0 = time.perf_counter()
            subprocess.run([sys.executable, __file__, "--example-worker", jpath, script, "--out", out], env=env,
                           cwd=str(ROOT), capture_output=True, text=True, check=True)
            r = json.load(open(jpath))
            os.unlink(jpath)
            r["wall_s"] = time.perf_counter() - t0
            res[phase] = r
    # the cold run instrumented, in a second empty cache: what it compiles
    with tempfile.TemporaryDirectory(prefix="qchain-numba-cache-") as cache, \
            tempfile.TemporaryDirectory(prefix="qchain-example-out-") as out:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
        with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as fh:
            jpath = fh.name
        t0 = time.perf_counter()
        subprocess.run([sys.executable, __file__, "--example-worker", jpath, script, "--out", out], env=env,
                       cwd=str(ROOT), capture_output=True, text=True, check=True)
        r = json.load(open(jpath))
        os.unlink(jpath)
        r["wall_s"] = time.perf_counter() - t0
        res["cold"] = r
    return res


def report_example(res: dict) -> None:
    def sim_line(stdout: str) -> str:
        return next((ln for ln in stdout.splitlines() if ln.startswith("simulated")), "?")

    print("\nexamples/wave_arm.py (the README's first command), whole command in a fresh interpreter:")
    print(f"  cold (empty cache): {res['cold_plain_s']:6.2f} s   [{sim_line(res['cold_stdout'])}]")
    print(f"  warm:               {res['warm_plain_s']:6.2f} s   [{sim_line(res['warm_stdout'])}]")
    for k in ("warm", "warm2"):
        r = res[k]
        nl = len(r["loads"])
        tl = sum(t for _, t, _ in r["loads"])
        first = r["loads"][0][1] if r["loads"] else 0.0
        print(f"  warm, instrumented: {r['wall_s']:6.2f} s wall; import qchain {r['import_s']:.2f} s; "
              f"{nl} numba cache loads {tl:.2f} s (the first {first:.2f} s, the other {nl - 1} "
              f"{(tl - first) / max(nl - 1, 1) * 1e3:.1f} ms each); "
              f"{len(r['compiles'])} compiles {sum(t for _, t in r['compiles']):.2f} s")
    r = res["cold"]
    print(f"  cold, instrumented: {r['wall_s']:6.2f} s wall; {len(r['compiles'])} top-level compiles "
          f"{sum(t for _, t in r['compiles']):.2f} s: " + ", ".join(
              f"{k.split('.', 1)[1]} {t:.1f} s" for k, t in sorted(r["compiles"], key=lambda kt: -kt[1])[:10]))
    mine = ("qchain.model.arc", "qchain.model.slices", "qchain.algorithms.recursive", "qchain.algorithms.rnea_derivatives",
            "qchain.algorithms.aba_derivatives")
    own = sum(t for k, t in r["every"].items() if k.startswith(mine))
    eng = sum(t for k, t in r["every"].items() if k.startswith("qchain.") and not k.startswith(mine))
    print(f"    exclusive compile time: kernels ({', '.join(m.split('.')[1] for m in mine)}) {own:.1f} s, "
          f"other qchain modules (engine, planar, ...) {eng:.1f} s, numba's own overloads "
          f"{sum(r['every'].values()) - own - eng:.1f} s; largest: " + ", ".join(
              f"{k.split('.', 1)[1]} {t:.1f}" for k, t in sorted(r["every"].items(), key=lambda kt: -kt[1])[:12]))
    r = res["warm"]
    by = {}
    for name, t, _ in r["loads"]:
        by[name] = by.get(name, 0.0) + t
    top = sorted(by.items(), key=lambda kv: -kv[1])[:8]
    print("  slowest loads: " + ", ".join(f"{k.split('.', 1)[1]} {1e3 * v:.0f} ms" for k, v in top))
    if r["compiles"]:
        print("  compiled on the warm run (not cached): " + ", ".join(sorted({k for k, _ in r["compiles"]})))


# ----------------------------------------------------------------------------- warm start


def _start_worker(t_parent: str, scene: str) -> None:
    """A fresh process with a warm cache: the README scene loaded, built and run as ``qchain
    run`` does, with the time since the parent started this process (``time.time()``) at each
    stage, up to the run's first step (its first output sample is handed over just before)."""
    t_spawn = float(t_parent)
    marks = {"interpreter": time.time() - t_spawn}
    import qchain  # noqa: F401
    from qchain.scene import load_scene

    marks["import"] = time.time() - t_spawn
    sc = load_scene(scene)
    marks["scene file"] = time.time() - t_spawn
    model = sc.build()
    marks["model"] = time.time() - t_spawn

    def on_sample(t, q, v, p):
        if "first step" not in marks:
            marks["first step"] = time.time() - t_spawn

    sc.simulate(model=model, on_sample=on_sample)
    print(json.dumps(marks))


def measure_start(repeat: int, scene: str) -> list[dict]:
    """``repeat`` fresh processes (after one that fills the cache), each timed to its first step."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    subprocess.run([sys.executable, __file__, "--start-worker", str(time.time()), scene], env=env, cwd=str(ROOT),
                   check=True, capture_output=True)
    runs = []
    for _ in range(repeat):
        t = time.time()
        p = subprocess.run([sys.executable, __file__, "--start-worker", str(t), scene], env=env, cwd=str(ROOT),
                           check=True, capture_output=True, text=True)
        runs.append(json.loads(p.stdout.strip().splitlines()[-1]))
    return runs


def report_start(runs: list[dict], scene: str) -> None:
    import numpy as np

    print(f"\nwarm start to the first step ({scene}, {len(runs)} fresh processes; seconds since the process "
          f"was started, median [min, max]):")
    for key in runs[0]:
        x = np.array([r[key] for r in runs])
        print(f"  {key:12s} {np.median(x):6.3f}  [{x.min():.3f}, {x.max():.3f}]")


# ----------------------------------------------------------------------------- driver


def _run(cache_dir: str) -> dict:
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as fh:
        out = fh.name
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, __file__, "--worker", out], check=True, env=env, cwd=str(ROOT))
    wall = time.perf_counter() - t0
    res = json.load(open(out))
    os.unlink(out)
    res["wall_s"] = wall
    return res


def measure() -> dict:
    with tempfile.TemporaryDirectory(prefix="qchain-numba-cache-") as cache:
        cold = _run(cache)
        nbi = sorted(Path(cache).rglob("*.nbi"))
        warm = _run(cache)
        # numba's cache locator for the kernels points into the temporary directory, which
        # received the index files; the warm run compiled nothing (every load a hit)
        honoured = (cold["cache_path"].startswith(cache) and bool(nbi) and not warm["compiles"]
                    and all(hit for *_, hit in warm["loads"]))
    return dict(cold=cold, warm=warm, cache_files=len(nbi), cache_honoured=honoured)


def report(runs: list[dict], show_signatures: bool) -> None:
    cold0, warm0 = runs[0]["cold"], runs[0]["warm"]
    print(f"NUMBA_CACHE_DIR honoured (kernels' cache path in it, index files there, warm run all hits): "
          f"{all(r['cache_honoured'] for r in runs)}; {runs[0]['cache_files']} index files")
    # cold: wall s (CPU s of the process in brackets: the compile is single-threaded, so CPU
    # time is what it costs on an idle core; wall time grows with the load of a shared machine)
    hdr = "  ".join(f"{'cold#' + str(i + 1) + ' wall (cpu)':>18}" for i in range(len(runs)))
    print(f"\n{'step':<16}{hdr}  {'warm s':>8}  {'2nd call ms':>11}")
    print(f"{'import qchain':<16}" + "  ".join(f"{r['cold']['import_s']:18.2f}" for r in runs)
          + f"  {warm0['import_s']:8.2f}")
    for k in cold0["steps"]:
        print(f"{k:<16}" + "  ".join(f"{r['cold']['steps'][k]:9.2f} ({r['cold']['cpu'][k]:6.2f})" for r in runs)
              + f"  {warm0['steps'][k]:8.3f}  {1e3 * warm0['again'][k]:11.3f}")
    print(f"{'total steps':<16}" + "  ".join(f"{sum(r['cold']['steps'].values()):9.2f} "
                                             f"({sum(r['cold']['cpu'].values()):6.2f})" for r in runs)
          + f"  {sum(warm0['steps'].values()):8.3f}")
    print(f"{'process wall':<16}" + "  ".join(f"{r['cold']['wall_s']:18.2f}" for r in runs)
          + f"  {warm0['wall_s']:8.2f}")

    # per top-level kernel: cold compile (inclusive of callees compiled for it), warm load
    print(f"\n{'top-level kernel (signature #)':<44}{'cold s':>8}{'warm load s':>12}")
    warm_load = {}
    for qual, mod, s, hit in warm0["loads"]:
        warm_load.setdefault(f"{mod.split('.')[-1]}.{qual}", []).append(s)
    seen = {}
    for c in cold0["compiles"]:
        if c["depth"] == 0:
            key = f"{c['module'].split('.')[-1]}.{c['name']}"
            seen[key] = seen.get(key, 0) + 1
            wl = warm_load.get(key, [])
            w = wl[seen[key] - 1] if len(wl) >= seen[key] else float("nan")
            print(f"{key + ' #' + str(seen[key]) + ' (' + c['step'] + ')':<44}{c['inclusive']:8.2f}{w:12.4f}")
    print(f"{'total':<44}{sum(c['inclusive'] for c in cold0['compiles'] if c['depth'] == 0):8.2f}"
          f"{sum(s for _, _, s, _ in warm0['loads']):12.4f}  ({len(warm0['loads'])} cache loads)")

    # per function: specialisations (compiles: jit dispatchers and register_jitable helpers
    # alike) and exclusive compile time
    excl = {}
    for c in cold0["compiles"]:
        key = f"{c['module']}.{c['name']}"
        excl.setdefault(key, []).append(c)
    print(f"\n{'function (compiled)':<46}{'sigs':>5}{'excl s':>8}{'of it LLVM':>11}{'incl s (max)':>13}")
    rows = sorted(excl.items(), key=lambda kv: -sum(c["exclusive"] for c in kv[1]))
    for name, cs in rows:
        print(f"{name:<46}{len(cs):>5}{sum(c['exclusive'] for c in cs):8.2f}{sum(c['llvm'] for c in cs):11.2f}"
              f"{max(c['inclusive'] for c in cs):13.2f}")
    nsig = len(cold0["compiles"])
    ndup = sum(len(cs) - 1 for cs in excl.values())
    print(f"{'all':<46}{nsig:>5}{sum(c['exclusive'] for c in cold0['compiles']):8.2f}"
          f"{sum(c['llvm'] for c in cold0['compiles']):11.2f}   "
          f"({ndup} duplicated specialisations)")
    dups = {k: [c["args"] for c in cs] for k, cs in excl.items() if len(cs) > 1}
    if dups:
        print("\nduplicated specialisations (same function, several argument types):")
        for k, v in dups.items():
            print(f"  {k}:")
            for s in v:
                print(f"      {s}")
    if show_signatures:
        print("\nall signatures (jit dispatchers' .signatures):")
        for k, v in cold0["signatures"].items():
            for s in v:
                print(f"  {k}: {s}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1, help="cold/warm pairs (cold times are noisy)")
    ap.add_argument("--json", type=Path, help="write the raw measurements here")
    ap.add_argument("--signatures", action="store_true", help="list every signature")
    ap.add_argument("--example", action="store_true", help="also time examples/wave_arm.py cold and warm")
    ap.add_argument("--no-kernels", action="store_true", help="skip the kernel table (with --example)")
    ap.add_argument("--start", type=int, default=0, metavar="N",
                    help="also time N warm fresh processes from their start to the first step")
    ap.add_argument("--scene", default="examples/scenes/wave_arm.toml", help="the scene of --start")
    ap.add_argument("--start-worker", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--example-worker", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        _worker(args.worker)
        return 0
    if args.example_worker:
        _example_worker(*args.example_worker)
        return 0
    if args.start_worker:
        _start_worker(*args.start_worker)
        return 0
    out = {}
    if not args.no_kernels:
        out["runs"] = runs = [measure() for _ in range(args.repeat)]
        report(runs, args.signatures)
    if args.example:
        out["example"] = ex = measure_example()
        report_example(ex)
    if args.start:
        out["start"] = st = measure_start(args.start, args.scene)
        report_start(st, args.scene)
    if args.json:
        args.json.write_text(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
