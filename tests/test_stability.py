"""The stability map's stress scenes (benchmarks/stability_map.py, quick settings): the
default method passes every scene, the paper's coordinates fail at kappa = 0 with the
documented error, and every failure is a clear error, never a crash or a NaN."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))

import stability_map  # noqa: E402

from qchain.simulate import simulate  # noqa: E402


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
