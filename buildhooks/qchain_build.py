"""qchain's build backend: setuptools', and at an editable install the engine compiled ahead.

An editable install (``pip install -e .``, the README's first command) runs qchain from this
source tree, so numba's on-disk cache written into the tree's ``__pycache__`` folders while
the install builds is the cache the first run loads: numba takes an entry when the source
file's modification time and size and numba's version are those it was written with (and the
machine's CPU), which an editable install leaves as they were. :func:`build_editable`
therefore runs :func:`warm_up` after setuptools has built the editable wheel: the default
method's engine for both right-hand sides and the energies' pass (in numba's worker processes,
:func:`qchain.compile_all`), and meanwhile, in the warm-up's own process, what the README's
example compiles there (its scene's model, a short run of it reduced and in full, the tips and
the backbone of its figure). A compiled source changed later (any file of
``qchain._jit.COMPILED_SOURCES``: qchain stamps its caches with all of them) compiles again
what is used at its first use, as without the warm-up, and the run says so on stderr.

Best effort: an install never fails because of the warm-up. A warm-up that fails, or takes
longer than :data:`TIMEOUT_S`, says so on stderr (pip shows a build's output with ``-v``) and
the first run compiles what is missing, as it would have. ``QCHAIN_INSTALL_COMPILE=0`` in the
environment, or ``--config-settings compile=0``, leaves it out (and its build requirements).

The warm-up runs in pip's isolated build environment, which holds what it needs besides
setuptools (:func:`get_requires_for_build_editable`: numba, numpy, scipy and Pinocchio with
the bounds of ``pyproject.toml``'s dependencies). numba's cache entries are valid only for the
numba version that wrote them, so where the target environment has numba already (a
reinstall), the build asks for that very version (and numpy's): :func:`_target_versions`.
A regular wheel (``pip install .``) is built as setuptools builds it: its files are copied
into site-packages with new modification times, so a cache written here would not be taken.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F401,F403  (every hook not wrapped below)

ROOT = Path(__file__).resolve().parent.parent
#: the runtime dependencies the warm-up imports (qchain's engine and its scene model)
WARMUP_DEPENDENCIES = ("numba", "numpy", "scipy", "pin")
#: packages whose versions must match between the build and the run for the cache to be taken
PINNED = ("numba", "numpy")
#: seconds after which the warm-up is given up (the first run compiles what is missing)
TIMEOUT_S = 1800
#: the environment variable (and config setting ``compile``) that turns the warm-up off with 0
SWITCH = "QCHAIN_INSTALL_COMPILE"


def _say(msg: str) -> None:
    print(f"qchain install: {msg}", file=sys.stderr, flush=True)


def enabled(config_settings=None) -> bool:
    """Whether the install compiles the engine: not if ``QCHAIN_INSTALL_COMPILE`` is ``0`` (or
    ``false``, ``no``, ``off``) or the config setting ``compile`` is."""
    value = (config_settings or {}).get("compile", os.environ.get(SWITCH, "1"))
    return str(value).strip().lower() not in ("0", "false", "no", "off")


def _dependencies() -> dict[str, str]:
    """``pyproject.toml``'s runtime dependencies of :data:`WARMUP_DEPENDENCIES`, by name."""
    import tomllib

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    out = {}
    for d in deps:
        name = re.match(r"[A-Za-z0-9_.-]+", d).group(0).lower()
        if name in WARMUP_DEPENDENCIES:
            out[name] = d
    return out


def _clean_env() -> dict[str, str]:
    """The environment without what pip's build isolation set: a process started with it and
    this interpreter sees the target environment's packages (pip runs the backend with the
    interpreter it installs into), not the build environment's."""
    env = dict(os.environ)
    for key in ("PYTHONPATH", "PYTHONNOUSERSITE", "PYTHONHOME"):
        env.pop(key, None)
    return env


def _target_versions() -> dict[str, str]:
    """The versions of :data:`PINNED` in the environment being installed into, where it has
    them from a package index through pip (empty for a fresh one, or if that cannot be told).
    One installed otherwise (conda, a local build, a file) may be a version no index has: asked
    for, it would fail the install, so it is left to ``pyproject.toml``'s bounds."""
    code = ("import importlib.metadata as m\n"
            f"for n in {PINNED!r}:\n"
            "    try: d = m.distribution(n)\n"
            "    except m.PackageNotFoundError: continue\n"
            "    if (d.read_text('INSTALLER') or '').strip() == 'pip' and d.read_text('direct_url.json') is None:\n"
            "        print(n, d.version)\n")
    try:
        p = subprocess.run([sys.executable, "-I", "-c", code], env=_clean_env(), capture_output=True, text=True,
                           timeout=60, check=True)
    except (OSError, subprocess.SubprocessError):
        return {}
    return dict(line.split(None, 1) for line in p.stdout.splitlines() if len(line.split()) == 2)


def warmup_requires() -> list[str]:
    """The build requirements of the warm-up: :data:`WARMUP_DEPENDENCIES` with
    ``pyproject.toml``'s bounds, numba and numpy at the target environment's versions where it
    has them."""
    deps = _dependencies()
    for name, version in _target_versions().items():
        deps[name] = f"{name}=={version}"
    return list(deps.values())


def get_requires_for_build_editable(config_settings=None):
    reqs = list(_setuptools.get_requires_for_build_editable(config_settings))
    if enabled(config_settings):
        try:
            reqs += warmup_requires()
        except Exception as err:  # best effort: the install goes on without the warm-up's packages
            _say(f"not compiling the engine ahead: its requirements could not be read ({err})")
    return reqs


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    name = _setuptools.build_editable(wheel_directory, config_settings, metadata_directory)
    if enabled(config_settings):
        warm_up()
    else:
        _say(f"not compiling the engine ahead ({SWITCH}=0): the first run compiles it")
    return name


def warm_up(timeout: float = TIMEOUT_S, python: str | None = None, env: dict | None = None) -> bool:
    """Compile the engine into numba's cache in the source tree (:func:`_compile`, in a new
    process of ``python``, default this one, with the tree first on its path); returns whether
    it succeeded. Never raises: a failure is said on stderr and the first run compiles."""
    env = dict(os.environ if env is None else env)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env.setdefault("MPLBACKEND", "Agg")
    cmd = [python or sys.executable, str(Path(__file__).resolve()), "--compile"]
    _say("compiling the default method's engine into numba's cache for the first run (one to two minutes of "
         "CPU, in parallel processes; QCHAIN_INSTALL_COMPILE=0 leaves it to the first run)")
    t0 = time.perf_counter()
    try:  # a session of its own: stopped, it is stopped with the compiling workers it started
        p = subprocess.Popen(cmd, cwd=str(ROOT), env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, start_new_session=True)
    except OSError as err:
        _say(f"compiling ahead could not start ({err}): the first run compiles the engine")
        return False
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except OSError:
            pass
        p.communicate()
        _say(f"compiling ahead took over {timeout:g} s and was stopped: the first run compiles what is missing")
        return False
    if p.returncode != 0:
        tail = (err or out).strip().splitlines()[-1:] or ["no output"]
        _say(f"compiling ahead failed (exit {p.returncode}: {tail[0]}): the first run compiles the engine")
        return False
    _say(f"engine compiled and cached in {time.perf_counter() - t0:.0f} s")
    return True


def _compile() -> None:
    """The warm-up's process: the default method's engine, both right-hand sides and the
    energies' pass, in numba's worker processes, while this one builds and runs the README
    example's scene (reduced, the planar kernel; and in full, the spatial one) as the example
    does, which compiles what a scene's run compiles in its own process."""
    import numpy as np

    from qchain import compile_all, load_scene
    from qchain.sim.engine import warmup
    from qchain.sim.simulation import DEFAULT_METHOD

    for planar_kernel in (True, False):  # the workers start now and compile while the scene runs below
        warmup.start(DEFAULT_METHOD, planar_kernel, energies=True, stream=None)
    scene = ROOT / "examples" / "scenes" / "wave_arm.toml"
    if scene.is_file():  # (a source tree without the examples: the engine only)
        sc = load_scene(scene)
        for reduce in (True, False):
            model = sc.build(reduce=reduce)
            sc.describe(model)
            traj = sc.simulate(model=model, duration=0.05)
            ch = model.chain
            np.array([ch.tip_placement(q, t=t).translation for t, q in zip(traj.t, traj.q)])
            ch.backbone(traj.q[-1], 16, t=traj.t[-1])
            batch_warm_up(model)
    compile_all([DEFAULT_METHOD], stream=None)  # waits for the workers, loads what they cached


def batch_warm_up(model) -> None:
    """Two rollouts of ``model`` in one batch with the default method and built-in pressure
    schedules: compiles :func:`qchain.sim.engine.batched.run_rollouts` (the compiled loop a
    thread of ``simulate_batch``) for this kernel into numba's cache, so a user's first
    batch does not wait for it."""
    import numpy as np

    from qchain import simulate_batch

    ch = model.chain
    simulate_batch(ch, model.q0, model.v0, (0.0, 0.01), pressure=np.zeros((2, ch.nu)), t_eval=[0.0, 0.01],
                   workers=1)


if __name__ == "__main__":
    if sys.argv[1:] == ["--compile"]:
        _compile()
    else:
        sys.exit("usage: python buildhooks/qchain_build.py --compile")
