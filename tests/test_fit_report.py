"""What a fit says (qchain.fit.report): the model points the report keeps are the start and
the fitted models' own (against equilibria computed here from the scenes), fit.json's values
are the report's, the summary and the picture."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest
from test_fit_statics import TRUTH, _poses, _scene

from qchain.fit import fit
from qchain.fit.report import FIGURE_HEIGHT, FIGURE_WIDTH, experiment_rms

KEYS = ["segments[0].youngs_modulus", "segments[1].chamber_area"]


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("report")
    scene = _scene(tmp, "arm.toml", E0=1.0e5)
    poses = _poses(tmp, noise=2e-4)
    rep = fit(scene, [poses], KEYS, values={KEYS[1]: 4.2e-5}, max_nfev=30)
    return rep, scene, poses


def _points_of(scene_text: str, path, poses):
    from qchain import equilibrium
    from qchain.scene.reading import parse_scene

    chain = parse_scene(scene_text, path).build(reduce=False).chain
    return np.array([chain.points(equilibrium(chain, p).q, poses.where) for p in poses.pressures])


def test_the_kept_points_are_the_start_and_fitted_models_own(report):
    import tomli_w

    from qchain.batch.sweep_spec import apply_values

    rep, scene, poses = report
    assert rep.result.x0[1] == 4.2e-5  # started where values= says, not at the scene's 5.0e-5
    fitted = _points_of(rep.scene_text(), scene, poses)
    np.testing.assert_allclose(rep.predicted("fitted")[0], fitted, atol=1e-9)
    start_raw = apply_values(tomllib.loads(scene.read_text()), {KEYS[1]: 4.2e-5})
    start = _points_of(tomli_w.dumps(start_raw), scene, poses)
    np.testing.assert_allclose(rep.predicted("start")[0], start, atol=1e-9)
    before, after = experiment_rms(rep)[0]
    assert after == pytest.approx(np.sqrt(np.mean(np.sum((fitted - poses.points) ** 2, axis=-1))), rel=1e-6)
    assert before == pytest.approx(np.sqrt(np.mean(np.sum((start - poses.points) ** 2, axis=-1))), rel=1e-6)
    assert after < before


def test_the_json_holds_the_reports_values(report):
    rep, _, _ = report
    data = json.loads(json.dumps(rep.to_dict()))  # (JSON as written: no NaN, no numpy)
    assert [p["key"] for p in data["parameters"]] == KEYS
    assert [p["value"] for p in data["parameters"]] == [float(x) for x in rep.result.x]
    assert [p["stderr"] for p in data["parameters"]] == [float(s) for s in rep.result.stderr]
    assert [p["start"] for p in data["parameters"]] == [1.0e5, 4.2e-5]
    np.testing.assert_array_equal(np.array(data["correlation"]), rep.result.correlation)
    assert data["counters"]["nfev"] == rep.result.nfev and data["counters"]["njev"] == rep.result.njev
    assert data["sigma_m"] == rep.result.sigma and data["wall_s"] > 0 and data["cpu_s"] > 0
    # two standard errors of a 0.2 mm-noise fit cover the truth here (seed 0)
    for p, truth in zip(data["parameters"], (TRUTH["E0"], TRUTH["A"])):
        assert abs(p["value"] - truth) < 2 * p["stderr"]


def test_the_summary_and_the_picture(report, tmp_path):
    rep, _, _ = report
    lines = rep.summary()
    assert lines[:3] == rep.result.table()
    assert any(line.startswith("experiment 0 (static, 8 poses)") for line in lines)
    fig = rep.plot()
    assert len(fig.axes) == 4
    assert len(fig.axes[0].lines) == 3  # measured, start, fitted
    np.testing.assert_allclose(fig.axes[0].lines[2].get_ydata(), rep.predicted("fitted")[0][:, 0, 0] * 1e3)
    path = rep.plot(tmp_path / "f.png", dpi=50)
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(data[16:20], "big") == round(FIGURE_WIDTH * 50)
    assert int.from_bytes(data[20:24], "big") == round(FIGURE_HEIGHT * 50)
    assert [p.name for p in tmp_path.iterdir()] == ["f.png"]  # (no temporary file left)
