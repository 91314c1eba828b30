"""The stability map's stress scenes (benchmarks/stability_map.py, quick settings): the
default method passes every scene, the paper's coordinates fail at kappa = 0 with the
documented error, and every failure is a clear error, never a crash or a NaN."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))

import stability_map  # noqa: E402

from qchain.sim.simulation import simulate  # noqa: E402


@pytest.mark.slow
def test_default_method_passes_every_scene_and_failures_are_clear(tmp_path):
    default = simulate.__kwdefaults__["method"]
    rows = [("default", default, "curvature"), ("rk4 (dt=1ms)", "rk4", "curvature"), ("paper", default, "paper")]
    cells = stability_map.run(quick=True, out_dir=tmp_path, wall=60.0, rows=rows)
    by = {(c.scene, c.row): c for c in cells}
    scenes = list(stability_map.scenes(True))
    for s in scenes:
        assert by[(s, "default")].passed, (s, by[(s, "default")].reason)
    straight = by[("through kappa = 0", "paper")]
    assert not straight.passed
    assert "paper's (l, psi, kappa) coordinates are singular" in straight.reason
    assert "coords='curvature'" in straight.reason
    for c in cells:
        assert not c.reason.startswith("CRASH"), c.reason
        if not c.passed:
            assert "segment" in c.reason and "t = " in c.reason, c.reason
    assert (tmp_path / "stability_map.png").stat().st_size > 10_000
    rows_csv = (tmp_path / "stability_map.csv").read_text().splitlines()
    assert len(rows_csv) == 1 + len(cells)
    assert np.isfinite([c.wall for c in cells]).all()


def _region_extent(A: np.ndarray, b: np.ndarray, half: float, step: float) -> float:
    """The largest |z| on a grid of spacing ``step`` over [-half, half]^2 where the explicit
    method (A, b) is stable, |R(z)| <= 1, with R(z) = sum_k z^k b^T A^(k-1) 1."""
    s = len(b)
    A = np.pad(A[:s, :s], ((0, s - min(s, A.shape[0])), (0, s - min(s, A.shape[1]))))  # square, s stages
    c, w = [1.0], np.ones(s)
    for _ in range(len(b)):
        c.append(float(b @ w))
        w = A @ w
    x = np.arange(-half, half + step / 2, step)
    Z = x[None, :] + 1j * x[:, None]
    stable = np.abs(np.polyval(c[::-1], Z)) <= 1.0
    return float(np.abs(Z[stable]).max())


@pytest.mark.slow
def test_explicit_stability_extents_bound_each_methods_stability_region():
    """EXPLICIT_STABILITY_EXTENT bounds every stable h |lambda| from above (so duration over
    the stability limit is a lower bound of the steps) and is within 0.05 of the region's
    reach: recomputed from the tableaus (ours for dopri5, scipy's for RK45 and DOP853)."""
    from scipy.integrate import RK45
    from scipy.integrate._ivp import dop853_coefficients as d853

    from qchain.sim.engine.driver import EXPLICIT_STABILITY_EXTENT as EXT
    from qchain.sim.engine.tableaus import DOPRI5_A

    step = 0.004
    for name, A, b in (("dopri5", DOPRI5_A[:6, :6], DOPRI5_A[6, :6]), ("RK45", RK45.A, RK45.B),
                       ("DOP853", d853.A, d853.B)):
        reach = _region_extent(np.asarray(A, float), np.asarray(b, float), 8.0, step)
        assert reach + step <= EXT[name] <= reach + 0.05, (name, reach, EXT[name])


def test_the_stability_limit_bounds_the_steps_dopri5_takes():
    """A ten-segment clamped rod: dopri5 takes at least duration / (its stability limit at the
    start) accepted steps, the lower bound the step budget is checked against."""
    from qchain import Chain, Segment
    from qchain.sim.simulation import explicit_stability_limit

    s = Segment(length=0.02, radius=0.01, mass=0.01, chamber_area=1e-5, chamber_radius=5e-3, youngs_modulus=5e5)
    ch = Chain([s] * 10)
    q, v = ch.neutral(), np.zeros(ch.nv)
    h = explicit_stability_limit(ch, "dopri5", q, v, 0.0)
    assert h is not None and 1e-4 < h < 1e-2
    for rtol in (1e-3, 1e-6):
        r = simulate(ch, q, v, (0.0, 0.5), method="dopri5", rtol=rtol, atol=rtol * 1e-3, t_eval=[0.5])
        assert r.success and r.meta["nsteps"] >= 0.5 / h, (rtol, r.meta["nsteps"], 0.5 / h)
