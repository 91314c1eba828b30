"""Cost at equal accuracy: a soft cantilever released under gravity, qchain against MuJoCo 4,
both against a converged unshearable extensible rod (MuJoCo hinge and slide links, reference C);
and the four-segment spatial arm
in ``pinocchio.aba`` calls.

Scene (SI units, the same numbers in every code): a rod of length L = 0.2 m, radius r = 0.02 m,
density rho = 1000 kg/m^3, Young's modulus E = 5e5 Pa, Poisson ratio nu = 0.5 (shear modulus
G = E / 3: PyElastica only, neither qchain nor MuJoCo has shear), clamped at the world origin,
straight along world +x and at rest at t = 0, then released under gravity (g = 9.81 m/s^2 along
-z), undamped, for T = 1 s (``--quick``: 0.5 s). Derived: A = pi r^2, EI = E pi r^4 / 4 =
0.0628 N m^2, EA = 628 N, mass 0.251 kg, first bending frequency 3.1 Hz, static tip deflection
under the same load (linear theory) 39 mm; every cross-section is a uniform rigid disk (rotary
inertia rho I per length) in every code.

References, all independent of qchain except B:

* **C**, the headline: the converged extensible rod, unshearable (the model class of qchain and
  MuJoCo's hinge rod). MuJoCo links as below with a slide joint along the parent's axis before
  each hinge, stiffness EA/h (2 EA/h at the clamp), RK4 at dt = 20 us; N = 20, 40, 80 (``--quick``:
  10, 20, 40), extrapolated in N at the order the three give (Richardson) when it is clean (within
  0.25 of an integer), else the finest run; checked in time by the finest at dt / 2. A different
  code and discretisation (rigid links, lumped springs) from qchain's (Cosserat strain modes).
* **A**, the sheared rod: PyElastica's converged extensible Cosserat rod with the material's shear
  modulus G = E/3 (bench_cosserat's ``elastica_run``: ``CosseratRod`` clamped with the rod started
  half an element inside the wall, ``PositionVerlet``): N = 100, 200, 400 elements at one step
  dt = 5 us (``--quick``: N = 50, 100, 200 at 10 us), extrapolated in N as C, checked in time by the
  finest at dt / 2.
* **B**, a cross-check: qchain's planar extensible rod with n = 32 segments (``dopri5`` at rtol
  1e-10; the output gives n = 16's distance and the n = 16/32 extrapolation's distance from C).
* **D**, a check of C from a third discretisation: PyElastica (N = 100) with the shear modulus
  scaled by 2, 4, 8 (and 32 in the full run), extrapolated to infinite shear stiffness at the order
  the three give. Beyond 4x, PyElastica's undamped rod grows an instability whose onset does not
  move when dt is halved or quartered (at N = 100 from 6x, at N = 200 from 4x; N = 50 stays stable
  to 32x): those runs carry PyElastica's ``LaplaceDissipationFilter`` of order 5, which moves the
  4x track by 0.018 mm RMS. D agrees with C only to about 0.5 mm (module output), so C, which needs
  no extrapolation in a material constant, is the headline.

Shear is not small here (r / L = 0.1, G = E/3): it lowers the bending frequencies (Timoshenko), and
the phase this loses over three swings puts every unshearable model several millimetres (RMS)
from A. So no run of qchain or MuJoCo can be within 1 mm of A; the table, the chart and the
headline measure against C; the output also gives the headline runs against B and the runs'
closest approach to A.
Every reference track is cached in ``<out>/release_cache/`` under a hash of everything it
depends on (scene, span, sampling, resolution, step, shear factor, filter, code and version); ``--fresh``
empties the cache first.

qchain: n equal segments (bench_cosserat's ``qchain_arm``, damping 0, tiny unpressurised
chambers; each segment's Gauss nodes sized for ``M_xi`` to :data:`NODE_TOLERANCE` at the bend this
scene can reach, :func:`release_bend` (twice the root segment's static bend), as a scene with
``model.max_bend`` sizes them: 3 a segment at n = 5 and 10, 2 from n = 14; the default is 6; the
output gives the largest bend any run reached against it), every method of
``qchain.sim.simulation.METHODS`` (read at run time): the fixed-step ones (``FIXED_STEP``) over
steps dt = 5 ms / 2^j, the others over rtol = 0.1 / 2^j to 1.6e-3 (:data:`RTOLS`: the settings
halve as MuJoCo's steps do), then 1e-4, 1e-5, ... (quick: decades; atol = rtol / 100; scipy's,
which run Python at every stage, over 1e-1, 1e-2, 1e-3; quick: down to 1e-2).
Two groups: **reduced**, the model this planar scene needs (``Chain(..., planar=True)``,
inextensible n = 5, 10, 20 and extensible n = 10, 20: the inextensible one qualifies where it
is within 1 mm like any run; quick: n = 10 inextensible), and **full spatial**
(``planar=False``, ``extensible=True``, n = 5, 10, 20; quick: 10: 3 coordinates a segment, the
model of a scene without reductions).

MuJoCo: N rigid links of length h = L/N (each a cylinder of radius r: mass rho A h and the rod's
rotary inertia), hinges about world y at the link ends (the first at the clamp), stiffness EI/h at
the interior hinges and 2 EI/h at the clamp (its Voronoi length is h/2), no damping, gravity, no
contacts, built as MJCF text; tip = a site at the end of the last link. Integrators Euler
(semi-implicit without damping), implicitfast, RK4, and MuJoCo 4's ``discrete`` where present,
over steps dt = 5 ms / 2^j (they divide the 10 ms sampling); N = 5, 10, 20, 40, 80 (quick: 10, 20).

Error: distance between the tip and the reference tip over samples every 10 ms in [0, T]; RMS
(the main figure) and max. "Converged in time": RMS distance to the finest successful run of
the same model and method (its sweep's last); a sweep goes from coarse to fine and stops after
a pair of neighbours closer than 0.005 mm, or when a run takes longer than the budget (the
finest run has no such figure; ``sweep`` says why not the next finer setting). Cost: **CPU seconds** (``time.process_time``: the
machine is shared, wall time would count the others' work) per simulated second of the
integration (model set-up excluded; qchain's kernels compiled by a warm-up run of every method
and model; ``energies=False`` and ``t_eval`` = the samples); median of 3 repeats for runs under
``repeat_below`` (2 s; quick: 0.3 s). Headline (against C): each group's cheapest run within 1 mm RMS
of reference C and converged in time to 0.2 mm; ratios qchain reduced / MuJoCo (target <= 0.5) and
qchain full spatial / MuJoCo (target <= 1.0), judged side by side: the headline runs timed again
in turn with MuJoCo's, 15 rounds, the median of the rounds' ratios (``side_by_side``); the
table's ratio column divides every sweep cost by the MuJoCo headline run's.

Arm (``--no-arm`` skips it): ``examples/scenes/spatial_arm.toml``, four segments driven in all
chambers, 12 free coordinates, 2 s (``--quick``: 1 s), every method over bench_precision's
settings; error: the largest tip distance from the converged tip path (``radau5`` rtol 1e-10,
checked against ``dopri5`` rtol 1e-10, both cached); cost: CPU seconds per simulated second,
median of repeats, and the same in calls of ``pinocchio.aba`` on the equal-nv rigid chain
(bench_precision's ``aba_call_s``, CPU time, in the same run). Headline: the cheapest run within
1 mm, in aba calls per simulated second (target <= 500).

Run: ``python benchmarks/bench_release.py [--quick] [--out DIR] [--n 5 10 20] [--N 5 10 20 40 80]
[--no-arm] [--fresh]``. Writes ``release.csv``, ``release_arm.csv`` and ``release.png`` into
``--out`` (default ``out/bench``). Redraw the chart from a written CSV (no runs):
``python benchmarks/replot.py [DIR]``.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import shutil
import time
from importlib import metadata
from pathlib import Path

import numpy as np

import _study
import bench_cosserat as bc

SCENE = dict(L=0.2, r=0.02, rho=1000.0, E=5e5, nu=0.5, g=9.81)  # m, m, kg/m^3, Pa, -, m/s^2
ACCURACY = 1e-3  # m RMS: the headline's accuracy level
CONVERGED = 2e-4  # m RMS: the headline's time-convergence level
STOP = 5e-6  # m RMS: a sweep stops after two neighbours this close
SIDE_ROUNDS = 15  #: rounds of the headline runs timed side by side (side_by_side)
TARGETS = {"qchain reduced": 0.5, "qchain full spatial": 1.0}  # cost / MuJoCo's, at most
ARM_TARGET = 500.0  # pinocchio.aba calls per simulated second, at most
ARM_ACCURACY = 1e-3  # m, largest tip distance
CLOCK = time.process_time  # CPU time of this process
#: relative M_xi accuracy the sweeps' node counts are sized for (the arm scene's node_tolerance)
NODE_TOLERANCE = 1e-6
CACHE_FORMAT = 1  # bump when a cached track's meaning changes
GROUPS = {"reduced": "qchain reduced", "full": "qchain full spatial", "mujoco": "mujoco"}
TITLES = {"reduced": "qchain, reduced (planar): n segments", "full": "qchain, full spatial model: n segments",
          "mujoco": "MuJoCo: N links", "qchain": "qchain: n segments"}


def release_bend(n: int, scene=SCENE) -> float:
    """The bend (rad, a segment's ``l |u|``) the n-segment cantilever's nodes are sized for:
    twice the static bend of the root segment under the rod's own weight, ``2 (w L^2 / 2 EI) L / n``
    with ``w = rho A g`` (a step load released from rest on an undamped linear structure peaks
    at twice its static deflection; the root carries the largest moment). The sweeps report the
    largest bend any run reached against it (:func:`run`)."""
    c = constants(scene)
    return 2.0 * (c["q"] * scene["L"] ** 2 / (2.0 * c["EI"])) * scene["L"] / n


def constants(scene=SCENE) -> dict:
    L, r, rho, E, g = (scene[k] for k in ("L", "r", "rho", "E", "g"))
    A = np.pi * r * r
    EI = E * np.pi * r**4 / 4
    return dict(A=A, EI=EI, EA=E * A, G=E / (2.0 * (1.0 + scene.get("nu", 0.5))), mass=rho * A * L, q=rho * A * g,
                f1=1.875104**2 / (2 * np.pi * L * L) * np.sqrt(EI / (rho * A)),
                w_static=rho * A * g * L**4 / (8 * EI))


def describe(scene=SCENE, T: float = 1.0) -> str:
    c = constants(scene)
    return (f"L = {scene['L']:g} m, r = {scene['r']:g} m, rho = {scene['rho']:g} kg/m^3, E = {scene['E']:g} Pa, "
            f"g = {scene['g']:g} m/s^2 along -z, undamped, T = {T:g} s; EI = {c['EI']:.4g} N m^2, "
            f"EA = {c['EA']:.4g} N, mass {c['mass']:.4g} kg, first bending frequency {c['f1']:.3g} Hz, "
            f"linear static tip deflection {1e3 * c['w_static']:.3g} mm")


# ---------------------------------------------------------------------------------- error measures


def tip_rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS over the samples of the distance between two tip tracks (K, 3) (m); nan if either
    is incomplete."""
    d = np.linalg.norm(a - b, axis=1)
    return float(np.sqrt(np.mean(d * d))) if np.all(np.isfinite(d)) else float("nan")


def richardson(coarse: np.ndarray, fine: np.ndarray, order: float = 2.0) -> np.ndarray:
    """Extrapolation of two tracks at resolutions N and 2N converging at ``order``:
    ``fine + (fine - coarse) / (2^order - 1)`` (second order: ``(4 fine - coarse) / 3``)."""
    return fine + (fine - coarse) / (2.0**order - 1.0)


def observed_order(x1: np.ndarray, x2: np.ndarray, x3: np.ndarray) -> float:
    """Convergence order of three tracks at N, 2N, 4N: ``log2(|x1 - x2| / |x2 - x3|)`` (RMS distances)."""
    return float(np.log2(tip_rms(x1, x2) / tip_rms(x2, x3)))


# ---------------------------------------------------------------------------------- MuJoCo


def mujoco_integrators() -> list[str]:
    import mujoco

    names = ["Euler", "implicitfast", "RK4"]
    if hasattr(mujoco.mjtIntegrator, "mjINT_DISCRETE"):
        names.append("discrete")  # MuJoCo 4: joint stiffness implicit (first order, dissipative)
    return names


def mujoco_xml(N: int, dt: float, integrator: str = "Euler", scene=SCENE, damping: float = 0.0,
               extensible: bool = False) -> str:
    """MJCF of the rod as N hinged rigid links along +x from the world origin (see the module
    docstring). ``damping`` (N m s/rad) is ``damping * stiffness`` at every hinge (stiffness-
    proportional, for a test that steps to rest); 0 in the benchmark.

    ``extensible=True`` adds a slide joint along the parent's axis before each hinge, stiffness
    EA/h (2 EA/h at the clamp, whose Voronoi length is h/2, as the hinge's): the unshearable
    extensible rod of reference C (no damping on it)."""
    L, r, rho, g = scene["L"], scene["r"], scene["rho"], scene["g"]
    c = constants(scene)
    h = L / N
    m = rho * c["A"] * h
    Ixx, Iyy = m * r * r / 2.0, m * (3.0 * r * r + h * h) / 12.0  # a cylinder along its x axis
    body = f'<site name="tip" pos="{_num(h)} 0 0"/>'
    for i in reversed(range(N)):
        f = 2.0 if i == 0 else 1.0
        k = f * c["EI"] / h
        pos = "0 0 0" if i == 0 else f"{_num(h)} 0 0"
        slide = (f'<joint name="slide{i}" type="slide" axis="1 0 0" pos="0 0 0" stiffness="{_num(f * c["EA"] / h)}" '
                 'springref="0"/>' if extensible else "")
        body = (f'<body name="link{i}" pos="{pos}">{slide}'
                f'<joint name="hinge{i}" type="hinge" axis="0 1 0" pos="0 0 0" stiffness="{_num(k)}" '
                f'damping="{_num(damping * k)}" springref="0"/>'
                f'<inertial pos="{_num(h / 2)} 0 0" mass="{_num(m)}" '
                f'diaginertia="{_num(Ixx)} {_num(Iyy)} {_num(Iyy)}"/>'
                f"{body}</body>")
    return (f'<mujoco model="release{N}"><option timestep="{_num(dt)}" integrator="{integrator}" '
            f'gravity="0 0 {_num(-g)}"><flag contact="disable" autoreset="disable"/></option>'
            f"<worldbody>{body}</worldbody></mujoco>")


def _num(x) -> str:
    """A number for MJCF text, to full precision (a numpy scalar's repr would name its type)."""
    return repr(float(x))


def mujoco_model(N: int, dt: float, integrator: str = "Euler", scene=SCENE, damping: float = 0.0,
                 extensible: bool = False):
    """``(MjModel, MjData)`` of the rod (``mujoco_xml``) at rest, straight."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(mujoco_xml(N, dt, integrator, scene, damping, extensible))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    return model, data


def mujoco_run(N: int, integrator: str, dt: float, T: float, repeat_below: float = 0.0, scene=SCENE,
               extensible: bool = False) -> dict:
    """Release the N-link rod; tips (K, 3) at ``bc.sample_times(T)``, cost (CPU s per simulated
    s) etc., as ``bc.qchain_run``. A run that goes non-finite or leaves 3 L stops as ``unstable``.
    ``extensible``: the links also slide (``mujoco_xml``)."""
    m = int(round(bc.SAMPLE / dt))
    if m < 1 or abs(m * dt - bc.SAMPLE) > 1e-9 * bc.SAMPLE:
        raise ValueError(f"dt = {dt:g} s must divide the sampling period {bc.SAMPLE:g} s")
    walls = []
    while True:
        tips, wall, status = _mujoco_once(N, integrator, dt, m, T, scene, extensible)
        walls.append(wall)
        if status != "ok" or len(walls) >= (3 if walls[0] < repeat_below else 1):
            break
    ok = status == "ok"
    return dict(tips=tips, cost=float(np.median(walls)) / T if ok else float("nan"), repeats=len(walls), ok=ok,
                status=status, work=int(round(T / dt)))


def _mujoco_once(N, integrator, dt, m, T, scene, extensible=False):
    import mujoco

    model, data = mujoco_model(N, dt, integrator, scene, extensible=extensible)
    site = model.site("tip").id
    K = int(round(T / bc.SAMPLE))
    tips = np.full((K + 1, 3), np.nan)
    tips[0] = data.site_xpos[site]
    far = 3.0 * scene["L"]
    bad = [int(getattr(mujoco.mjtWarning, w)) for w in ("mjWARN_BADQPOS", "mjWARN_BADQVEL", "mjWARN_BADQACC")]
    status = "ok"
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda msg: None)  # an unstable step is reported in the row, not on stderr
    try:
        t0 = CLOCK()
        for k in range(1, K + 1):
            mujoco.mj_step(model, data, nstep=m)
            mujoco.mj_kinematics(model, data)  # the site at the new time (mj_step leaves the old one)
            tip = data.site_xpos[site]
            if (any(data.warning[w].number for w in bad) or not np.all(np.isfinite(tip))
                    or np.linalg.norm(tip) >= far):
                status = f"unstable at t = {k * bc.SAMPLE:.2f} s"
                break
            tips[k] = tip
        wall = CLOCK() - t0
    finally:
        mujoco.set_mju_user_warning(previous)
    return tips, wall, status


# ---------------------------------------------------------------------------------- qchain


def qchain_methods() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``(METHODS, FIXED_STEP)`` of qchain.sim.simulation as they are now."""
    import qchain.sim.simulation as qs

    return tuple(qs.METHODS), tuple(qs.FIXED_STEP)


def qchain_setting(method: str, value: float, fixed: tuple) -> dict:
    return dict(dt=value) if method in fixed else dict(rtol=value, atol=value / 100.0)


def qchain_warmup(configs) -> None:
    """A short run of every method on every ``(n, planar, extensible)`` model: compiles what each compiles."""
    from qchain.sim.simulation import simulate

    methods, fixed = qchain_methods()
    for n, planar, ext in configs:
        ch = bc.qchain_arm(n, SCENE, extensible=ext, planar=planar)
        for method in methods:
            kw = qchain_setting(method, 1e-3 if method in fixed else 1e-4, fixed)
            simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 0.004), method=method, energies=False, **kw)


def variant_name(planar: bool, extensible: bool) -> str:
    return f"{'planar' if planar else 'spatial'} {'extensible' if extensible else 'inextensible'}"


# ---------------------------------------------------------------------------------- references


def cached_track(cache: Path | None, name: str, key: dict, compute) -> tuple[np.ndarray, float, bool]:
    """A reference tip track (K, 3), computed by ``compute() -> (tips, cpu_s)`` or read from
    ``cache/<name>-<hash of key>.npz``; returns ``(tips, cpu_s, from_cache)``. ``cache=None``
    always computes. The key (JSON) is stored beside the track and compared on reading."""
    blob = json.dumps(dict(key, format=CACHE_FORMAT), sort_keys=True)
    path = None
    if cache is not None:
        path = cache / f"{name}-{hashlib.sha1(blob.encode()).hexdigest()[:12]}.npz"
        if path.exists():
            with np.load(path) as z:
                if str(z["key"]) == blob:
                    return np.array(z["tips"]), float(z["cpu_s"]), True
    tips, cpu = compute()
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, tips=tips, key=np.array(blob), cpu_s=cpu)
        tmp.replace(path)
    return tips, cpu, False


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "?"


def elastica_track(N: int, dt: float, T: float, cache: Path | None, shear_factor: float = 1.0,
                   filter_order: int | None = None):
    """PyElastica's rod with N elements at step dt (bench_cosserat's ``elastica_run``), cached;
    ``filter_order``: PyElastica's Laplace dissipation filter on the rates (None: none)."""
    key = dict(code="pyelastica", version=_version("pyelastica"), scene=SCENE, T=T, sample=bc.SAMPLE, N=N, dt=dt,
               shear_factor=shear_factor, clamp="half an element inside the wall")
    if filter_order is not None:
        key["filter_order"] = filter_order  # absent without one: the cached unfiltered tracks stay valid

    def compute():
        t0 = CLOCK()
        res = bc.elastica_run(N, dt, T, scene=SCENE, shear_factor=shear_factor, filter_order=filter_order)
        reach = float(np.max(np.linalg.norm(res["tips"], axis=1)))
        if res["ok"] and reach > 1.01 * SCENE["L"]:  # the rod stretches by ~1e-3 at most: a blow-up inside 3 L
            res.update(ok=False, status=f"unstable: the tip reached {reach:.3g} m from the clamp")
        if not res["ok"]:
            raise RuntimeError(f"PyElastica reference N = {N}, dt = {dt:g} s, shear modulus x{shear_factor:g}, "
                               f"filter order {filter_order} failed: {res['status']}")
        return res["tips"], CLOCK() - t0

    return cached_track(cache, f"pyelastica-N{N}", key, compute)


def mujoco_rod_track(N: int, dt: float, T: float, cache: Path | None):
    """Reference C's run: MuJoCo's N links with hinges and slides (``mujoco_xml(extensible=True)``),
    RK4 at step dt, cached."""
    import mujoco

    key = dict(code="mujoco", version=mujoco.__version__, scene=SCENE, T=T, sample=bc.SAMPLE, N=N, dt=dt,
               integrator="RK4", joints="slide then hinge, clamp 2x")

    def compute():
        t0 = CLOCK()
        res = mujoco_run(N, "RK4", dt, T, scene=SCENE, extensible=True)
        if not res["ok"]:
            raise RuntimeError(f"MuJoCo reference rod N = {N}, dt = {dt:g} s failed: {res['status']}")
        return res["tips"], CLOCK() - t0

    return cached_track(cache, f"mujoco-ext-N{N}", key, compute)


def qchain_track(n: int, extensible: bool, method: str, rtol: float, T: float, cache: Path | None):
    """qchain's planar rod, n segments, at a tight tolerance (a converged reference), cached."""
    key = dict(code="qchain", scene=SCENE, T=T, sample=bc.SAMPLE, n=n, planar=True, extensible=extensible,
               method=method, rtol=rtol, atol=rtol / 100.0)

    def compute():
        t0 = CLOCK()
        res = bc.qchain_run(n, T, method, scene=SCENE, extensible=extensible, rtol=rtol, atol=rtol / 100.0)
        if not res["ok"]:
            raise RuntimeError(f"qchain reference n = {n} ({variant_name(True, extensible)}) failed: {res['status']}")
        return res["tips"], CLOCK() - t0

    return cached_track(cache, f"qchain-n{n}-{'ext' if extensible else 'inext'}", key, compute)


def references(cfg: dict, T: float, cache: Path | None) -> tuple[dict, list[str]]:
    """The references: ``({"unshearable": C, "cosserat": A, "qchain": B, "note", "note_a", "note_b"},
    report lines)``.

    C (the headline): the unshearable extensible rod as MuJoCo links joined by hinges and slides,
    extrapolated in N. A: the extensible Cosserat rod with the material's shear modulus
    (PyElastica, extrapolated in N). B: qchain's planar extensible rod (n = ``q_ref_n``, tight
    dopri5). D (a check of C): PyElastica with the shear modulus scaled up, extrapolated to
    infinite shear stiffness (module docstring).
    """
    lines = []

    def say(what, cpu, hit):
        print(f"reference: {what}: {'cached' if hit else f'{cpu:.1f} s CPU'}", flush=True)

    def extrapolate(tracks: dict, what: str, unit: str, ratio: float = 2.0):
        """Richardson on the last two of three tracks at the observed order when it is clean
        (within 0.25 of an integer >= 1), else the last; ``(track, order, how)``."""
        k = list(tracks)
        p = observed_order(*(tracks[x] for x in k[-3:]))
        if abs(p - round(p)) <= 0.25 and round(p) >= 1:
            return richardson(tracks[k[-2]], tracks[k[-1]], round(p)), p, (
                f"{what} = {k[-2]:g} and {k[-1]:g}{unit} Richardson-extrapolated at order {round(p)}")
        return tracks[k[-1]], p, f"{what} = {k[-1]:g}{unit} (not extrapolated: observed order {p:.2f})"

    def ladder(tracks: dict, what: str, unit: str = "") -> str:
        k = list(tracks)
        return ", ".join(f"{what} = {a:g}/{b:g}{unit}: {1e3 * tip_rms(tracks[a], tracks[b]):.4f} mm"
                         for a, b in zip(k, k[1:]))

    # C: MuJoCo, hinges and slides, converged in N and checked in time
    Nc, dtc = cfg["mj_Ns"], cfg["mj_dt"]
    mj = {}
    for N in Nc:
        mj[N], cpu, hit = mujoco_rod_track(N, dtc, T, cache)
        say(f"MuJoCo N = {N} hinge + slide links, RK4 dt = {dtc * 1e6:g} us", cpu, hit)
    mj_half, cpu, hit = mujoco_rod_track(Nc[-1], dtc / 2, T, cache)
    say(f"MuJoCo N = {Nc[-1]} hinge + slide links, RK4 dt = {dtc / 2 * 1e6:g} us (check in time)", cpu, hit)
    C, pc, how_c = extrapolate(mj, "N", "")
    note = (f"converged extensible rod, unshearable (the model class of qchain and MuJoCo's hinge rod): MuJoCo "
            f"links joined by hinges (EI/h) and slides (EA/h), RK4 dt = {dtc * 1e6:g} us, {how_c}")
    lines.append(f"reference C (the headline): {note}")
    lines.append(f"  convergence in N: RMS differences {ladder(mj, 'N')}; observed order {pc:.2f}; N = {Nc[-1]} is "
                 f"{1e3 * tip_rms(mj[Nc[-1]], C):.4f} mm RMS from C; in time, N = {Nc[-1]} at dt/2 is "
                 f"{1e3 * tip_rms(mj_half, mj[Nc[-1]]):.2e} mm RMS from dt")

    # A: the sheared Cosserat rod
    Ns, dt = cfg["pe_Ns"], cfg["pe_dt"]
    pe = {}
    for N in Ns:
        pe[N], cpu, hit = elastica_track(N, dt, T, cache)
        say(f"PyElastica N = {N}, dt = {dt * 1e6:g} us", cpu, hit)
    fine, cpu, hit = elastica_track(Ns[-1], dt / 2, T, cache)
    say(f"PyElastica N = {Ns[-1]}, dt = {dt / 2 * 1e6:g} us (check in time)", cpu, hit)
    A, pa, how_a = extrapolate(pe, "N", "")
    note_a = f"converged extensible Cosserat rod with shear: PyElastica (G = E/3), dt = {dt * 1e6:g} us, {how_a}"
    lines.append(f"reference A (the sheared rod): {note_a}")
    lines.append(f"  convergence in N: RMS differences {ladder(pe, 'N')}; observed order {pa:.2f}; N = {Ns[-1]} is "
                 f"{1e3 * tip_rms(pe[Ns[-1]], A):.4f} mm RMS from A; in time, N = {Ns[-1]} at dt/2 is "
                 f"{1e3 * tip_rms(fine, pe[Ns[-1]]):.5f} mm RMS from dt")
    lines.append(f"  A is {1e3 * tip_rms(A, C):.3f} mm RMS ({1e3 * bc.tip_error(A, C):.3f} max) from C: the shear that "
                 "every unshearable model leaves out (r / L = 0.1), so no run of qchain or MuJoCo can be within 1 mm "
                 "of A")

    # B: qchain's own, a cross-check
    n, rtol = cfg["q_ref_n"], cfg["q_ref_rtol"]
    q = {}
    for m in (n // 2, n):
        q[m], cpu, hit = qchain_track(m, True, "dopri5", rtol, T, cache)
        say(f"qchain n = {m} planar extensible, dopri5 rtol {rtol:g}", cpu, hit)
    B = q[n]
    kirchhoff, cpu, hit = qchain_track(n, False, "dopri5", rtol, T, cache)
    say(f"qchain n = {n} planar inextensible, dopri5 rtol {rtol:g}", cpu, hit)
    note_b = f"qchain planar extensible n = {n}, dopri5 rtol {rtol:g} (not independent)"
    lines.append(f"reference B (cross-check): {note_b}")
    lines.append(f"  B is {1e3 * tip_rms(B, C):.4f} mm RMS ({1e3 * bc.tip_error(B, C):.4f} max) from C; n = {n // 2} is "
                 f"{1e3 * tip_rms(q[n // 2], B):.4f} mm from B, and n = {n // 2}/{n} extrapolated at order 2 is "
                 f"{1e3 * tip_rms(richardson(q[n // 2], B), C):.4f} mm from C; the inextensible rod (n = {n}) is "
                 f"{1e3 * tip_rms(kirchhoff, C):.3f} mm RMS from C (the axial stretch)")

    # D: PyElastica towards infinite shear stiffness, a check of C
    Nm, fo = cfg["pe_N_mid"], cfg["pe_filter"]
    sh = {}
    for f in cfg["pe_shear"]:
        order = fo if f > 4.0 else None  # beyond 4x the undamped rod goes unstable at N = 100 (module docstring)
        sh[f], cpu, hit = (pe[Nm], 0.0, True) if f == 1.0 and Nm in pe else elastica_track(Nm, dt, T, cache, f, order)
        say(f"PyElastica N = {Nm}, dt = {dt * 1e6:g} us, shear modulus x{f:g}"
            + (f", Laplace filter order {order}" if order else ""), cpu, hit)
    ext = {f: sh[f] for f in cfg["pe_shear_extrapolate"]}
    D, pd, how_d = extrapolate(ext, "shear x", "")
    lines.append(f"reference D (check of C): PyElastica N = {Nm} with stiffer shear: "
                 + ", ".join(f"x{f:g} {1e3 * tip_rms(sh[f], C):.3f}" for f in sh)
                 + f" mm RMS from C; {how_d} towards infinite shear stiffness (observed order {pd:.2f}) is "
                 f"{1e3 * tip_rms(D, C):.3f} mm RMS from C and {1e3 * tip_rms(D, B):.3f} mm from B")
    return dict(unshearable=C, cosserat=A, qchain=B, note=note, note_a=note_a, note_b=note_b), lines


# ---------------------------------------------------------------------------------- study


#: the adaptive methods' sweep: rtol halving from 0.1, as the fixed steps halve from 5 ms, to
#: 1.6e-3, then decades to 1e-9
RTOLS = [1e-1 / 2**j for j in range(7)] + [10.0**-k for k in range(4, 10)]


def settings(quick: bool) -> dict:
    steps = [5e-3 / 2**j for j in range(10)]  # 5 ms .. 9.8 us, all divide 10 ms
    if quick:
        return dict(T=0.5, reduced=[(10, False)], full=[10], Ns=[10, 20],
                    pe_Ns=(50, 100, 200), pe_dt=1e-5, pe_N_mid=100, q_ref_n=32, q_ref_rtol=1e-10,
                    mj_Ns=(10, 20, 40), mj_dt=2e-5, pe_shear=(1.0, 2.0, 4.0, 8.0), pe_shear_extrapolate=(2.0, 4.0, 8.0),
                    pe_filter=5,
                    steps=steps[:8], rtols=[1e-1, 1e-2, 1e-3, 1e-4, 1e-5], scipy_rtols=[1e-1, 1e-2],
                    repeat_below=0.3, budget=2.0, arm_T=1.0)
    return dict(T=1.0, reduced=[(5, False), (10, False), (20, False), (10, True), (20, True)], full=[5, 10, 20],
                Ns=[5, 10, 20, 40, 80], pe_Ns=(100, 200, 400), pe_dt=5e-6, pe_N_mid=100, q_ref_n=32,
                mj_Ns=(20, 40, 80), mj_dt=2e-5, pe_shear=(1.0, 2.0, 4.0, 8.0, 32.0),
                pe_shear_extrapolate=(2.0, 4.0, 8.0), pe_filter=5,
                q_ref_rtol=1e-10, steps=steps, rtols=RTOLS,
                scipy_rtols=[1e-1, 1e-2, 1e-3], repeat_below=2.0, budget=10.0, arm_T=None)


def _fmt_setting(kind: str, value: float) -> str:
    return f"dt={value * 1e3:g}ms" if kind == "dt" else f"rtol={value:g}"


def sweep(runner, values, kind: str, budget: float, T: float) -> list[dict]:
    """Run ``runner(value)`` from coarse to fine; each row gets ``value``, ``kind`` and
    ``time_conv_m``: its RMS tip distance from the finest successful run of the sweep, the
    same model converged in time as far as the sweep went (nan for that run itself and for a
    failed one). Stops after two neighbours within ``STOP``, or after a run costlier than
    ``budget`` s (its repeats included).

    The distance to the finest run, not to the next finer setting: a neighbour's distance
    depends on how far apart the settings lie (10x in rtol against 2x in a step) and can
    pass a run whose neighbour shares its error, where the finest run does not."""
    rows = []
    for v in values:
        res = runner(v)
        res.update(value=v, kind=kind, setting=_fmt_setting(kind, v), time_conv_m=float("nan"))
        step = (tip_rms(rows[-1]["tips"], res["tips"]) if rows and rows[-1]["ok"] and res["ok"]
                else float("nan"))
        rows.append(res)
        print(f"    {res['setting']:<16} {res['cost']:9.4f} s/s  {res['status']}"
              + (f"  (previous vs this {1e3 * step:.4f} mm)" if np.isfinite(step) else ""), flush=True)
        if step < STOP:
            break
        if res["ok"] and res["cost"] * T * res["repeats"] > budget:
            break
    finest = next((r for r in reversed(rows) if r["ok"]), None)
    for r in rows:
        if r["ok"] and r is not finest:
            r["time_conv_m"] = tip_rms(r["tips"], finest["tips"])
    return rows


def run(quick: bool = False, out_dir: Path = Path("out/bench"), ns=None, Ns=None, arm: bool = True,
        fresh: bool = False) -> list[dict]:
    """Run the study; write ``release.csv``, ``release.png`` (and ``release_arm.csv``) into
    ``out_dir``; return the rows of the release."""
    cfg = settings(quick)
    if ns:
        cfg["reduced"] = [(n, ext) for n in ns for ext in (False, True)]
        cfg["full"] = list(ns)
    if Ns:
        cfg["Ns"] = list(Ns)
    T, rb, budget = cfg["T"], cfg["repeat_below"], cfg["budget"]
    out_dir = Path(out_dir)
    cache = out_dir / "release_cache"
    if fresh and cache.exists():
        shutil.rmtree(cache)  # every reference recomputed, then cached again
    methods, fixed = qchain_methods()
    integrators = mujoco_integrators()
    import mujoco

    print(f"scene: {describe(SCENE, T)}", flush=True)
    print(f"qchain methods {methods} (fixed step: {fixed}); MuJoCo {mujoco.__version__}, integrators {integrators}; "
          f"PyElastica {_version('pyelastica')}; cost in CPU time (time.process_time)", flush=True)
    t_start = time.perf_counter()
    rows: list[dict] = []

    def add(code, group, model, n, variant, method, res):
        res.setdefault("time_conv_m", float("nan"))
        rows.append(dict(code=code, group=group, model=model, n=n, variant=variant, method=method, role="sweep",
                         T_s=T, **res))

    configs = [(n, True, ext) for n, ext in cfg["reduced"]] + [(n, False, True) for n in cfg["full"]]
    qchain_warmup([(2, True, False), (2, True, True)] + configs)
    ref, ref_lines = references(cfg, T, cache)
    for line in ref_lines:
        print(line, flush=True)

    # ---- qchain sweeps
    for (n, planar, ext), method in itertools.product(configs, methods):
        kind = "dt" if method in fixed else "rtol"
        values = (cfg["steps"] if kind == "dt" else cfg["rtols"] if method in ("radau5", "dopri5")
                  else cfg["scipy_rtols"])
        variant = variant_name(planar, ext)
        group = "reduced" if planar else "full"
        print(f"qchain n = {n} {variant} {method}", flush=True)

        def runner(v, n=n, ext=ext, planar=planar, method=method):
            return bc.qchain_run(n, T, method, rb, scene=SCENE, extensible=ext, planar=planar, clock=CLOCK,
                                 node_tolerance=NODE_TOLERANCE, max_bend=release_bend(n),
                                 **qchain_setting(method, v, fixed))

        model = f"n={n}" + ("" if planar else " 3D") + (" ext" if ext and planar else "")
        for res in sweep(runner, values, kind, budget, T):
            add("qchain", group, model, n, variant, method, dict(res, planar=planar, extensible=ext))

    # ---- MuJoCo sweeps
    mujoco_run(4, "Euler", 1e-3, bc.SAMPLE)  # warm-up
    for N, integ in itertools.product(cfg["Ns"], integrators):
        print(f"MuJoCo N = {N} {integ}", flush=True)
        for res in sweep(lambda v, N=N, integ=integ: mujoco_run(N, integ, v, T, rb), cfg["steps"], "dt", budget, T):
            add("mujoco", "mujoco", f"N={N}", N, "", integ, res)

    # ---- errors, headline
    for r in rows:
        tips = r.pop("tips")
        for suffix, x in (("", ref["unshearable"]), ("_vs_shearable", ref["cosserat"]), ("_vs_qchain_ref", ref["qchain"])):
            r[f"rms{suffix}_m" if suffix else "rms_error_m"] = tip_rms(tips, x) if r["ok"] else float("nan")
            r[f"max{suffix}_m" if suffix else "max_error_m"] = bc.tip_error(tips, x) if r["ok"] else float("nan")
        r["cpu_per_sim_s"] = r.pop("cost") if r["ok"] else float("nan")  # a failed run has no cost
        r.pop("max_kappa_r", None)
    _node_sizing(rows)
    best = best_runs(rows)
    side = side_by_side(best, T, fixed)
    base = best["mujoco"]["cpu_per_sim_s"] if best["mujoco"] else float("nan")
    for r in rows:
        r["cost_ratio"] = r["cpu_per_sim_s"] / base if np.isfinite(base) else float("nan")
        r["reference"] = ref["note"]
    release_s = time.perf_counter() - t_start

    print_table(rows)
    # reference A: the errors against the shearable rod in the columns the rule reads
    lines = ref_lines + ["against reference C, the converged unshearable extensible rod (table, chart):"]
    lines += headline(rows, best, ratios=TARGETS, side=side)
    rows_b = [dict(r, rms_error_m=r["rms_vs_qchain_ref_m"], max_error_m=r["max_vs_qchain_ref_m"]) for r in rows]
    best_b = best_runs(rows_b)
    lines.append("against reference B, qchain's own n = 32 rod (cross-check): "
                 + "; ".join(f"{GROUPS[g]} " + (f"{_name(r)} {cost_of(r):.4g} s/s" if r else "none")
                             for g, r in best_b.items())
                 + "; ratios " + ", ".join(
                     f"{GROUPS[g]} / MuJoCo {cost_of(best_b[g]) / cost_of(best_b['mujoco']):.3g}"
                     for g in ("reduced", "full") if best_b[g] and best_b["mujoco"]))
    rows_a = [dict(r, rms_error_m=r["rms_vs_shearable_m"], max_error_m=r["max_vs_shearable_m"]) for r in rows]
    best_a = best_runs(rows_a)
    floor = {g: min((r["rms_error_m"] for r in rows_a if r.get("group") == g and r["ok"]), default=float("nan"))
             for g in GROUPS}
    lines.append("against reference A, the sheared Cosserat rod: qualifying runs: "
                 + "; ".join(f"{GROUPS[g]} " + (f"{_name(r)} {cost_of(r):.4g} s/s" if r else "none")
                             for g, r in best_a.items())
                 + "; closest any run comes to A (RMS): "
                 + ", ".join(f"{GROUPS[g]} {_mm(x)} mm" for g, x in floor.items()))
    for line in lines:
        print(line)
    fields = ["code", "group", "model", "n", "variant", "method", "role", "setting", "value", "kind", "T_s",
              "rms_error_m", "max_error_m", "rms_vs_shearable_m", "max_vs_shearable_m", "rms_vs_qchain_ref_m",
              "max_vs_qchain_ref_m", "time_conv_m", "cpu_per_sim_s",
              "cost_ratio", "work", "nodes", "max_bend", "repeats", "status", "reference"]
    _study.write_csv([{k: r.get(k, "") for k in fields} for r in rows], out_dir / "release.csv")
    plot(rows, out_dir / "release.png", T, ref["note"], best)
    print(f"wrote {out_dir / 'release.csv'} and {out_dir / 'release.png'} ({release_s:.1f} s of wall time)")
    if arm:
        import bench_release_arm

        bench_release_arm.run(quick, out_dir, cache, T=cfg["arm_T"])
    print(f"bench_release: {time.perf_counter() - t_start:.1f} s of wall time in all", flush=True)
    return rows


def _node_sizing(rows: list[dict]) -> None:
    """Print the largest segment bend of the qchain runs within :data:`ACCURACY` of reference C
    against the bend their nodes were sized for (:func:`release_bend`): the quadrature of a run
    that can qualify is the one it was sized for. (A run far from the rod, an explicit method
    at a step it barely survives, may bend further: it cannot qualify.)"""
    bends = [(r["max_bend"] / release_bend(r["n"]), r["n"], r["max_bend"]) for r in rows
             if r["code"] == "qchain" and r["ok"] and r["rms_error_m"] <= ACCURACY]
    if not bends:
        return
    worst = max(bends)
    print(f"node sizing: the largest segment bend of the qchain runs within {ACCURACY * 1e3:g} mm is {worst[2]:.3f} "
          f"rad (n = {worst[1]}), {worst[0]:.2f} of the {release_bend(worst[1]):.3f} rad its nodes were sized for"
          + ("" if worst[0] <= 1.0 else ": EXCEEDED, the quadrature is not what the nodes were sized for"), flush=True)


def side_by_side(best: dict, T: float, fixed: tuple, rounds: int = SIDE_ROUNDS) -> dict:
    """Each qchain group's headline run and MuJoCo's timed again in turn, ``rounds`` times:
    per group the median and quartiles of the rounds' cost ratios to MuJoCo's, and the median
    costs (CPU s per simulated s). The sweeps time the two headline runs minutes apart, over
    which this machine's speed drifts by tens of per cent; a ratio of two runs taken one
    after the other cancels that drift. Empty where MuJoCo has no qualifying run."""
    runs = {g: _rerun(r, T, fixed) for g, r in best.items() if r is not None}
    if "mujoco" not in runs:
        return {}
    costs = {g: [] for g in runs}
    for _ in range(rounds):
        for g, run in runs.items():
            costs[g].append(run())
    m = np.array(costs["mujoco"])
    out = {}
    for g in runs:
        if g != "mujoco":
            ratio, q1, q3 = _study.spread(np.array(costs[g]) / m)
            out[g] = dict(ratio=ratio, q1=q1, q3=q3, cost=float(np.median(costs[g])), mujoco=float(np.median(m)),
                          rounds=rounds)
    return out


def _rerun(r: dict, T: float, fixed: tuple):
    """A function that runs the sweep row ``r``'s setting once more and returns its cost."""
    if r["code"] == "mujoco":
        return lambda: mujoco_run(r["n"], r["method"], r["value"], T)["cost"]
    kw = qchain_setting(r["method"], r["value"], fixed)
    return lambda: bc.qchain_run(r["n"], T, r["method"], scene=SCENE, extensible=r["extensible"], planar=r["planar"],
                                 clock=CLOCK, node_tolerance=NODE_TOLERANCE, max_bend=release_bend(r["n"]),
                                 **kw)["cost"]


def eligible(r: dict, accuracy: float = ACCURACY) -> bool:
    """A sweep run within ``accuracy`` m RMS of the reference and converged in time to ``CONVERGED``."""
    return (r["role"] == "sweep" and r["ok"] and r["rms_error_m"] <= accuracy and np.isfinite(r["time_conv_m"])
            and r["time_conv_m"] <= CONVERGED)


def cost_of(r: dict) -> float:
    """A row's cost per simulated second: CPU time here, wall time in bench_contact's rows."""
    return r["cpu_per_sim_s"] if "cpu_per_sim_s" in r else r["wall_per_sim_s"]


def cheapest(rows: list[dict], code: str, keep=lambda r: True, accuracy: float = ACCURACY) -> dict | None:
    cand = [r for r in rows if r["code"] == code and eligible(r, accuracy) and keep(r)]
    return min(cand, key=cost_of) if cand else None


def best_runs(rows: list[dict], accuracy: float = ACCURACY) -> dict:
    """The cheapest eligible run of each group (``reduced``, ``full``, ``mujoco``), None where none."""
    return {g: cheapest(rows, "mujoco" if g == "mujoco" else "qchain", lambda r, g=g: r.get("group") == g, accuracy)
            for g in GROUPS}


def _name(r: dict) -> str:
    return f"{r['code']} {r['model']} {r['method']} {r['setting']}"


def headline(rows: list[dict], best: dict, ratios: dict | None = None, side: dict | None = None) -> list[str]:
    """The headline lines: each entry of ``best`` (its cheapest eligible run), the ratio of each
    to MuJoCo's (``ratios``: label -> target, where there is one; judged on the side-by-side
    ratio of ``side``, :func:`side_by_side`, where given), then the same at tighter accuracy
    levels and per method. ``best`` maps a group (or a code) to a row or None."""
    labels = {k: GROUPS.get(k, k) for k in best}
    m = best.get("mujoco")
    lines = [f"headline: the cheapest run within {ACCURACY * 1e3:g} mm RMS of the reference and converged in time to "
             f"{CONVERGED * 1e3:g} mm RMS (cost: {'CPU' if rows and 'cpu_per_sim_s' in rows[0] else 'wall'} "
             "seconds per simulated second)"]
    for key, r in best.items():
        if r is None:
            lines.append(f"  {labels[key]}: no run qualifies")
        else:
            lines.append(f"  {labels[key]}: {_name(r)}: {cost_of(r):.4g} s per simulated second "
                         f"(error {1e3 * r['rms_error_m']:.3f} mm RMS, {1e3 * r['max_error_m']:.3f} max; "
                         f"time convergence {1e3 * r['time_conv_m']:.4f} mm)")
    for key, r in best.items():
        if key == "mujoco":
            continue
        target = (ratios or {}).get(labels[key])
        verdict = ""
        if r and m:
            x = cost_of(r) / cost_of(m)
            sb = (side or {}).get(key)
            y = sb["ratio"] if sb else x
            if target is not None:
                verdict = f" (target <= {target:g}: {'met' if y <= target else 'NOT met'})"
            if sb:
                lines.append(f"  ratio {labels[key]} / MuJoCo: {y:.3g} side by side (quartiles {sb['q1']:.3g}-"
                             f"{sb['q3']:.3g} over {sb['rounds']} rounds: {1e3 * sb['cost']:.4g} against "
                             f"{1e3 * sb['mujoco']:.4g} ms per simulated second); the sweeps' costs give {x:.3g}"
                             f"{verdict}")
            else:
                lines.append(f"  ratio {labels[key]} / MuJoCo: {x:.3g}{verdict}")
        elif target is not None:
            lines.append(f"  ratio {labels[key]} / MuJoCo: none (a side has no qualifying run; target <= {target:g}: "
                         "NOT met)")
    lines.append("  at other accuracy levels (same rule):")
    for acc in (5e-4, 2e-4, 1e-4):
        at = {k: cheapest(rows, "mujoco" if k == "mujoco" else "qchain",
                          (lambda r, k=k: r.get("group", r["code"]) == k) if k in GROUPS else (lambda r: True), acc)
              for k in best}
        parts = [f"{labels[k]} " + (f"{cost_of(r):.4g} s/s [{r['model']} {r['method']} {r['setting']}]" if r else
                                   "none") for k, r in at.items()]
        lines.append(f"    {acc * 1e3:g} mm: " + "; ".join(parts))
    lines.append("  per method (cheapest qualifying run):")
    for key in best:
        code = "mujoco" if key == "mujoco" else "qchain"
        mine = [r for r in rows if r["code"] == code and r["role"] == "sweep" and r.get("group", code) in (key, code)]
        for method in dict.fromkeys(r["method"] for r in mine):
            r = cheapest(mine, code, lambda r, method=method: r["method"] == method)
            lines.append(f"    {labels[key]:<20} {method:<13} " + (
                f"{cost_of(r):.4g} s/s  [{r['model']} {r['setting']}, {1e3 * r['rms_error_m']:.3f} mm]"
                if r else "none"))
    return lines


# ---------------------------------------------------------------------------------- output


def _mm(x: float, fmt: str = ".3f") -> str:
    return format(1e3 * x, fmt) if np.isfinite(x) else "-"


def _short(status: str, width: int = 60) -> str:
    """A failed run's message cut for the table (the CSV has all of it)."""
    return status if len(status) <= width else status[: width - 3] + "..."


def print_table(rows: list[dict]) -> None:
    print(f"{'code':<7} {'model':<11} {'method':<13} {'step / tol':<16} {'RMS (mm)':>9} {'max (mm)':>9} "
          f"{'vs A':>9} {'vs B':>9} {'t-conv (mm)':>11} {'CPU s/s':>9} {'x MuJoCo':>9} {'rep':>3}  status")
    for r in rows:
        ratio = f"{r['cost_ratio']:.3g}" if np.isfinite(r["cost_ratio"]) else "-"
        cost = f"{r['cpu_per_sim_s']:.4f}" if np.isfinite(r["cpu_per_sim_s"]) else "-"
        mark = " *" if eligible(r) else ""
        print(f"{r['code']:<7} {r['model']:<11} {r['method']:<13} {r['setting']:<16} {_mm(r['rms_error_m']):>9} "
              f"{_mm(r['max_error_m']):>9} {_mm(r['rms_vs_shearable_m']):>9} {_mm(r['rms_vs_qchain_ref_m']):>9} "
              f"{_mm(r['time_conv_m'], '.4f'):>11} "
              f"{cost:>9} {ratio:>9} {r['repeats']:>3}  {_short(r['status'])}{mark}")
    print(f"(RMS, max: tip distance to reference C, the converged unshearable extensible rod, over samples every "
          f"{bc.SAMPLE * 1e3:g} ms; vs A: RMS distance to reference A, the sheared Cosserat rod; vs B: to qchain's "
          f"n = 32 extensible rod; t-conv: RMS "
          f"distance to the finest run of the same model and method; CPU s/s: CPU seconds per simulated "
          f"second; x MuJoCo: cost over the MuJoCo headline run's; "
          f"*: within {ACCURACY * 1e3:g} mm RMS and converged in time to {CONVERGED * 1e3:g} mm)")


def frontier(runs: list[dict]) -> list[dict]:
    """The runs no other run beats in both RMS error and cost, in order of falling error.

    Parameters
    ----------
    runs : list of dict
        Rows with finite ``rms_error_m`` (m) and cost (``cost_of``, s/s).
    """
    front = []
    for r in sorted(runs, key=lambda r: (cost_of(r), r["rms_error_m"])):
        if not front or r["rms_error_m"] < front[-1]["rms_error_m"]:
            front.append(r)
    return front


def plot(rows: list[dict], path: Path, T: float, ref_note: str, best: dict) -> None:
    """Cost against accuracy, one panel a group (a row's ``group``, else its ``code``).

    Each line joins a model size's frontier: the runs (of any method and setting) that no other run
    of that size beats in both RMS error and cost; grey dots are the other runs. Filled: converged in
    time to ``CONVERGED``; hollow: not, or not measured. Circled: each panel's headline run (``best``,
    keyed by group or code). ``T`` and ``ref_note`` describe the scene and reference (in the README's
    caption, not the chart).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sweeps = [r for r in rows if r["role"] == "sweep" and r["ok"] and np.isfinite(r["rms_error_m"])
              and r["rms_error_m"] > 0 and np.isfinite(cost_of(r))]
    panels = list(dict.fromkeys(r.get("group") or r["code"] for r in rows if r["role"] == "sweep"))
    fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 5.6), sharex=True, sharey=True,
                             squeeze=False)
    for ax, panel in zip(axes[0], panels):
        mine = [r for r in sweeps if (r.get("group") or r["code"]) == panel]
        models = list(dict.fromkeys(r["model"] for r in mine))
        colors = plt.cm.viridis(np.linspace(0.0, 0.85, max(len(models), 1)))
        ax.plot([r["rms_error_m"] for r in mine], [cost_of(r) for r in mine], ".", color="0.75", ms=4,
                zorder=1, label="other runs")
        for model, color in zip(models, colors):
            front = frontier([r for r in mine if r["model"] == model])
            ax.plot([r["rms_error_m"] for r in front], [cost_of(r) for r in front], "-", color=color,
                    lw=1.5, zorder=2, label=model)
            for r in front:
                conv = np.isfinite(r["time_conv_m"]) and r["time_conv_m"] <= CONVERGED
                ax.plot(r["rms_error_m"], cost_of(r), "o", color=color, ms=5, mfc=color if conv else "white",
                        zorder=3)
        r = best.get(panel)
        if r is not None:
            ax.plot(r["rms_error_m"], cost_of(r), "o", ms=15, mfc="none", mec="k", mew=1.5, zorder=4)
            ax.annotate(f"cheapest: {r['model']} {r['method']} {r['setting']}\n{cost_of(r):.3g} s/s",
                        (r["rms_error_m"], cost_of(r)), textcoords="offset points", xytext=(10, -22),
                        fontsize=8)
        _study.threshold(ax, ACCURACY, f"{ACCURACY * 1e3:g} mm RMS (headline bound)")
        ax.plot([], [], "o", color="k", mfc="white", ms=5, label=f"hollow: not converged to {CONVERGED * 1e3:g} mm")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{TITLES.get(panel, panel)}, best runs per size", fontsize=10)
        ax.set_xlabel("RMS tip error against the reference (m)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    cpu = bool(rows) and "cpu_per_sim_s" in rows[0]
    axes[0][0].set_ylabel(f"{'CPU' if cpu else 'wall'} time per simulated second (s)")
    _study.save(fig, path)


def replot(csv_path: Path, png_path: Path) -> None:
    """Redraw the chart from a written ``release.csv`` (no runs)."""
    rows = _study.read_csv(Path(csv_path))
    for r in rows:
        for k in ("time_conv_m", "rms_error_m", "max_error_m", "cpu_per_sim_s", "wall_per_sim_s"):
            if k in r and r[k] == "":
                r[k] = float("nan")
        r["ok"] = r["status"] == "ok"
    best = best_runs(rows) if "group" in rows[0] else {c: cheapest(rows, c) for c in ("qchain", "mujoco")}
    plot(rows, png_path, rows[0]["T_s"], rows[0]["reference"], best)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="T = 0.5 s, n = 10 and fewer settings (a few minutes)")
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the CSV and PNG files")
    ap.add_argument("--n", type=int, nargs="+", help="qchain segment counts (default 5 10 20; quick: 10)")
    ap.add_argument("--N", type=int, nargs="+", dest="N_links",
                    help="MuJoCo link counts (default 5 10 20 40 80; quick: 10 20)")
    ap.add_argument("--no-arm", action="store_true", help="skip the four-segment spatial arm")
    ap.add_argument("--fresh", action="store_true", help="recompute the reference tracks (ignore the cache)")
    args = ap.parse_args(argv)
    return run(args.quick, args.out, ns=args.n, Ns=args.N_links, arm=not args.no_arm, fresh=args.fresh)


if __name__ == "__main__":
    main()
