"""The qchain side of benchmarks/bench_cosserat.py (the released soft cantilever), on a
short run: the tip error against a 16-segment qchain reference falls as n grows. No
PyElastica needed."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))

import bench_cosserat as bc  # noqa: E402
import pytest

T = 0.15  # s: the tip has fallen about 6 cm, with a bent, not yet swinging, shape
TOL = dict(rtol=1e-6, atol=1e-8)  # DOP853 here is step-limited by stability: integration error ~1e-10 m


@pytest.mark.slow
def test_released_cantilever_converges_with_the_segment_count():
    ref = bc.qchain_run(16, T, "DOP853", **TOL)
    assert ref["ok"], ref["status"]
    L = bc.SCENE["L"]
    np.testing.assert_allclose(ref["tips"][0], [L, 0.0, 0.0], atol=1e-12)  # straight along +x at t = 0
    assert np.all(np.abs(ref["tips"][:, 1]) < 1e-12)  # planar: stays in the x-z plane
    assert ref["tips"][-1, 2] < -0.04  # it falls
    assert ref["max_kappa_r"] < 0.2  # well inside the model's domain (|kappa| r < 1)
    errs = []
    for n in (1, 2, 4):
        res = bc.qchain_run(n, T, "DOP853", **TOL)
        assert res["ok"], res["status"]
        assert res["tips"].shape == (len(bc.sample_times(T)), 3)
        errs.append(bc.tip_error(res["tips"], ref["tips"]))
    # measured: 1.8e-2, 4.4e-3, 1.2e-3 m
    assert errs[0] > 2.5 * errs[1] > 2.5 * 2.5 * errs[2], errs
    assert errs[2] < 2e-3, errs


def test_frontier_and_cost_at_equal_error():
    pts = [(1.0, 1e-2), (2.0, 2e-2), (4.0, 1e-3), (8.0, 1e-3), (16.0, 1e-4), (0.5, float("nan"))]
    front = bc.frontier(pts)
    assert front == [(1.0, 1e-2), (4.0, 1e-3), (16.0, 1e-4)]  # dominated and failed points dropped
    assert bc.cost_at(front, 1e-2) == 1.0
    np.testing.assert_allclose(bc.cost_at(front, np.sqrt(1e-2 * 1e-3)), 2.0)  # log-log midpoint
    assert np.isnan(bc.cost_at(front, 1e-1)) and np.isnan(bc.cost_at(front, 1e-5))  # no extrapolation
