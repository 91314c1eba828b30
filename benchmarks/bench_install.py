"""The README's first command end to end, as a new user runs it: install, then the first run.

For each variant, a clone of the repository's committed ``HEAD`` in a temporary folder (no
numba cache in it), then, timed apart (wall and CPU time of the command and its children):

1. ``python3 -m venv .venv`` (not timed) and ``.venv/bin/pip install -q -e .``: the install,
   with the build backend's warm-up (``buildhooks/qchain_build.py``) or without it
   (``QCHAIN_INSTALL_COMPILE=0``);
2. ``.venv/bin/python examples/wave_arm.py``: the first run after the install, then a second.

Variants: ``compile`` (the install compiles the engine ahead, the default) and ``off`` (it
does not: the first run compiles, as before the backend). The machine's load average is
printed beside each step (the machine is shared: wall times grow with it, CPU times much less).

Run: ``python benchmarks/bench_install.py [--variants compile,off] [--keep DIR]``
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _timed(cmd: list[str], cwd: Path, env: dict) -> tuple[float, float, subprocess.CompletedProcess]:
    """Wall and CPU seconds (the children's user + system time) of ``cmd``."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=str(cwd), env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stdout[-2000:]}\n{p.stderr[-4000:]}")
    return wall, (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime), p


def _load() -> str:
    return f"{os.getloadavg()[0]:.1f}"


def run_variant(variant: str, where: Path) -> list[tuple]:
    src = where / variant
    subprocess.run(["git", "clone", "-q", str(ROOT), str(src)], check=True)
    env = dict(os.environ, MPLBACKEND="Agg")
    for key in ("PYTHONPATH", "NUMBA_CACHE_DIR", "VIRTUAL_ENV"):
        env.pop(key, None)
    if variant == "off":
        env["QCHAIN_INSTALL_COMPILE"] = "0"
    subprocess.run([sys.executable, "-m", "venv", ".venv"], cwd=str(src), check=True)
    rows = []
    load = _load()
    wall, cpu, _ = _timed([".venv/bin/pip", "install", "-q", "-e", "."], src, env)
    rows.append((variant, "pip install -q -e .", wall, cpu, load, ""))
    env.pop("QCHAIN_INSTALL_COMPILE", None)
    for k in ("first", "second"):
        load = _load()
        wall, cpu, p = _timed([".venv/bin/python", "examples/wave_arm.py"], src, env)
        said = next((ln for ln in p.stderr.splitlines() if ln.startswith("qchain: compiling")), "")
        rows.append((variant, f"examples/wave_arm.py ({k} run)", wall, cpu, load, said))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", default="compile,off", help="comma-separated: compile, off")
    ap.add_argument("--keep", type=Path, help="build the clones and venvs here and keep them")
    args = ap.parse_args(argv)
    variants = [v for v in args.variants.split(",") if v]
    bad = [v for v in variants if v not in ("compile", "off")]
    if bad:
        raise SystemExit(f"--variants: unknown {bad}; choose from compile, off")
    where = args.keep or Path(tempfile.mkdtemp(prefix="qchain-install-"))
    where.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        for v in variants:
            rows += run_variant(v, where)
    finally:
        if args.keep is None:
            shutil.rmtree(where, ignore_errors=True)
    print(f"{'variant':<9}{'step':<34}{'wall s':>8}{'cpu s':>8}{'load':>6}  stderr")
    for v, step, wall, cpu, load, said in rows:
        print(f"{v:<9}{step:<34}{wall:8.1f}{cpu:8.1f}{load:>6}  {said[:110]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
