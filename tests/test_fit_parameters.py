"""Fit parameters named by scene keys (qchain.fit.parameters): start values and bounds from the
scene, the fitted values written back into a scene that builds, shared parameters' columns."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from qchain.batch.sweep_spec import apply_values
from qchain.fit.parameters import column_map, fit_parameters, scene_values

SCENE = Path(__file__).parents[1] / "examples" / "scenes" / "spatial_arm.toml"  # one table, count = 4


def _raw(two_tables: bool = False) -> dict:
    raw = tomllib.loads(SCENE.read_text())
    if two_tables:  # the first segment apart: tables [0] (count 1) and [1] (count 3)
        first = dict(raw["segments"][0], count=1, youngs_modulus=2e5)
        raw["segments"] = [first, dict(raw["segments"][0], count=3)]
    return raw


def test_keys_read_their_start_values_and_the_formats_bounds():
    raw = _raw(two_tables=True)
    ps = fit_parameters(raw, ["segments[0].youngs_modulus", "segments[1].damping", "segments[*].mass", "gravity[2]"],
                        bounds={"segments[0].youngs_modulus": (1e4, 1e6)})
    E, d, m, g = ps
    assert (E.start, E.lower, E.upper, E.unit, E.segments) == (2e5, 1e4, 1e6, "Pa", (0,))
    assert (d.start, d.lower, d.upper, d.segments) == (0.02, 0.0, 100.0, (1, 2, 3))
    assert (m.start, m.segments) == (0.05, (0, 1, 2, 3))
    assert (g.name, g.component, g.start, g.segments) == ("gravity", 2, -9.81, ())


def test_fitted_values_go_back_into_a_scene_that_builds():
    from qchain.scene.reading import parse_scene
    import tomli_w

    raw = _raw(two_tables=True)
    ps = fit_parameters(raw, ["segments[1].youngs_modulus", "segments[*].mass", "gravity[2]"])
    new = apply_values(raw, scene_values(ps, [1.5e5, 0.06, -9.7]))
    scene = parse_scene(tomli_w.dumps(new))
    chain = scene.build(reduce=False).chain
    assert [s.youngs_modulus for s in chain.segments] == [2e5, 1.5e5, 1.5e5, 1.5e5]
    assert [s.mass for s in chain.segments] == [0.06] * 4
    assert chain.gravity[2] == -9.7


def test_a_shared_parameter_sums_its_segments_columns():
    raw = _raw(two_tables=True)
    ps = fit_parameters(raw, ["segments[1].youngs_modulus", "gravity[0]"])
    cols = [("youngs_modulus", s) for s in range(4)] + [("gravity", k) for k in range(3)]
    T = column_map(ps, cols)
    np.testing.assert_array_equal(T[:, 0], [0, 1, 1, 1, 0, 0, 0])
    np.testing.assert_array_equal(T[:, 1], [0, 0, 0, 0, 1, 0, 0])
    with pytest.raises(ValueError, match=r"segments\[1\].youngs_modulus: the model has no derivative column"):
        column_map(ps, cols[:1] + cols[4:])


def test_bad_keys_and_bounds_are_refused_by_name():
    raw = _raw(two_tables=True)
    with pytest.raises(ValueError, match=r"'segments\[0\].radius' is not a parameter a fit can change; those are: "
                                         r"segments\[i\].youngs_modulus"):
        fit_parameters(raw, ["segments[0].radius"])
    with pytest.raises(ValueError, match=r"segments\[5\].mass: the scene has 2 \[\[segments\]\] tables"):
        fit_parameters(raw, ["segments[5].mass"])
    with pytest.raises(ValueError, match=r"segments\[\*\].youngs_modulus: the tables have different values"):
        fit_parameters(raw, ["segments[*].youngs_modulus"])
    with pytest.raises(ValueError, match=r"lower bound 0\.5 is below the scene format's 1 Pa"):
        fit_parameters(raw, ["segments[0].youngs_modulus"], bounds={"segments[0].youngs_modulus": (0.5, None)})
    with pytest.raises(ValueError, match=r"the start value 200000 Pa is outside the bounds \[1, 1000\]"):
        fit_parameters(raw, ["segments[0].youngs_modulus"], bounds={"segments[0].youngs_modulus": (None, 1e3)})
    with pytest.raises(ValueError, match="is given twice"):
        fit_parameters(raw, ["gravity[2]", "gravity[2]"])
    with pytest.raises(ValueError, match=r"bounds for 'gravity\[1\]', which is not one of the fitted keys"):
        fit_parameters(raw, ["gravity[2]"], bounds={"gravity[1]": (0, 1)})


def test_gravity_is_named_one_way_by_the_parameters_the_sensitivities_and_the_fit():
    """``("gravity", axis)`` is one column and ``("gravity", None)`` the three axes in turn, for
    :meth:`Chain.parameters` (the rest poses' derivatives) and :func:`qchain.sim.sensitivities`
    alike; the fit hands both the same pairs (``_model_params``), and their columns agree."""
    from qchain.fit.fitting import _model_params
    from qchain.scene.reading import parse_scene
    from qchain.sim.sensitivity import sensitivities

    raw = _raw()
    params = fit_parameters(raw, ["segments[*].mass", "gravity[2]", "gravity[0]"])
    pairs = _model_params(params)
    assert pairs == [("mass", 0), ("mass", 1), ("mass", 2), ("mass", 3), ("gravity", 2), ("gravity", 0)]
    import tomli_w

    chain = parse_scene(tomli_w.dumps(raw)).build(reduce=False).chain
    P = chain.parameters(pairs)
    assert [n for n in P.names if n.startswith("gravity")] == ["gravity z [m/s^2]", "gravity x [m/s^2]"]
    rng = np.random.default_rng(0)
    q = np.tile([chain.segments[0].length, 0.0, 0.0], chain.n) + rng.normal(size=chain.nq) * np.tile([0, 1, 1], chain.n)
    v, p = 0.1 * rng.normal(size=chain.nv), rng.uniform(0, 2e4, chain.nu)
    one = chain.forward_dynamics_parameter_derivatives(q, v, p, [("gravity", 2)]).da_dtheta
    all3 = chain.forward_dynamics_parameter_derivatives(q, v, p, [("gravity", None)]).da_dtheta
    np.testing.assert_array_equal(one[:, 0], all3[:, 2])
    with pytest.raises(ValueError, match=r"\('gravity', 1\) is named twice"):
        chain.parameters([("gravity", None), ("gravity", 1)])
    with pytest.raises(ValueError, match=r"axis of 'gravity' must be None \(all three\) or an int in \[0, 2\]"):
        chain.parameters([("gravity", 3)])
    # the sensitivities read the same pairs: ("gravity", None) is the three axes' columns
    q0 = np.tile([chain.segments[0].length, 0.5, 0.0], chain.n)
    a = sensitivities(chain, q0, np.zeros(chain.nv), (0.0, 0.05), params=[("gravity", None)], initial=False,
                      method="rk4", dt=0.01)
    b = sensitivities(chain, q0, np.zeros(chain.nv), (0.0, 0.05), params=[("gravity", k) for k in range(3)],
                      initial=False, method="rk4", dt=0.01)
    assert a.columns == b.columns == ["gravity[0]", "gravity[1]", "gravity[2]"]
    np.testing.assert_array_equal(a.S, b.S)


def test_a_scene_with_tendons_is_refused():
    """The measured inputs are chamber pressures: a fit of a scene with tendons is refused,
    not run with the tendons slack."""
    raw = _raw()
    raw["tendons"] = [{"radius": 0.01}]
    with pytest.raises(ValueError, match=r"a fit takes no tendons \(\[\[tendons\]\]\)"):
        fit_parameters(raw, ["segments[0].youngs_modulus"])
