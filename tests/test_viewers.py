"""What the viewers get: Rerun's own MCAP importer, the Rerun blueprint (camera, plots), the
Foxglove layout."""

from __future__ import annotations

import io
import json
import subprocess

import numpy as np
import pytest
from logging_fixtures import arm_info, arm_records

from qchain.logging import TOPICS, RunInfo, RunLogger, foxglove_layout
from qchain.recording.rerun_sink import FOV_Y_DEG, _quat_rot, camera, rerun_cli


def _quat_about_x(angle):
    return np.array([np.sin(angle / 2), 0.0, 0.0, np.cos(angle / 2)])


@pytest.mark.parametrize("angle", [0.0, np.pi, np.pi / 2, 2.0])
def test_the_camera_frames_the_arms_reach_whatever_the_base_orientation(angle):
    """Every point the arm can reach (a ball of its length about the base, on the base's
    side) is inside the camera's field of view, hanging, standing or sideways."""
    base = np.array([0.1, -0.2, 0.5, *_quat_about_x(angle)])
    reach = 0.3
    eye, target, up = camera(base, reach)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(4000, 3))
    d *= (rng.uniform(size=(4000, 1)) ** (1 / 3)) / np.linalg.norm(d, axis=1, keepdims=True)
    z_b = _quat_rot(base[3:])[:, 2]
    pts = base[:3] + reach * d
    pts = pts[(pts - base[:3]) @ z_b >= -0.2 * reach]  # the arm does not fold far behind its base
    view = target - eye
    view /= np.linalg.norm(view)
    to = pts - eye
    cos = to @ view / np.linalg.norm(to, axis=1)
    assert np.degrees(np.arccos(cos.min())) < 0.5 * FOV_Y_DEG  # inside the vertical field (the narrower)
    # the arm's middle is the view's centre: half a reach along the base axis
    np.testing.assert_allclose(target, base[:3] + 0.5 * reach * z_b)
    assert up @ view < 0.9  # not looking straight down the up vector


def test_rerun_plots_are_named_with_units_and_span_the_run(tmp_path):
    import rerun as rr

    info = arm_info(q_names=[f"segment {i // 3 + 1} {c} [{u}]" for i, (c, u) in
                             enumerate([("l", "m"), ("ux", "1/m"), ("uy", "1/m")] * 3)], duration=0.25)
    rrd = tmp_path / "run.rrd"
    with RunLogger(info, io.BytesIO(), rrd=rrd, quiet=True) as log:
        for r in arm_records(50):
            log.log(r)
    names = {}
    for chunk in rr.chunk.RrdReader(rrd).stream():
        if chunk.is_static:
            rb = chunk.to_record_batch()
            for col in rb.schema.names:
                if col.endswith(":names"):
                    names[chunk.entity_path] = rb.column(rb.schema.names.index(col)).to_pylist()[0]
    assert names["/plots/q/segment_2"] == ["segment 2 l [m]", "segment 2 ux [1/m]", "segment 2 uy [1/m]"]
    assert names["/plots/pressure"][4] == "segment 2 chamber 2 [Pa]"
    assert names["/plots/energy"] == ["kinetic [J]", "potential [J]", "total [J]"]
    from qchain.logging import RecordLayout
    from qchain.recording.records import Batch
    from qchain.recording.rerun_sink import RerunSink

    sink = RerunSink.__new__(RerunSink)  # the blueprint alone, as a run sends it
    import rerun.blueprint as rrb

    sink.rr, sink.rrb, sink.info = rr, rrb, info
    rows = np.stack([np.concatenate(([r.t, r.step], r.q, r.v, r.p, [r.kinetic, r.potential, r.total],
                                     [*r.backbone[0, 0], 0, 0, 0, 1], r.backbone.ravel(), r.tip_frames.ravel()))
                     for r in arm_records(3)])
    bp = sink.blueprint(Batch.from_rows(rows, RecordLayout(9, 9, 9, 3, 12)))
    views, todo = [], [bp.root_container]
    while todo:
        node = todo.pop()
        if hasattr(node, "contents") and isinstance(node.contents, (list, tuple)):
            todo += node.contents
        if type(node).__name__ == "TimeSeriesView":
            views.append(node)
    assert len(views) == 6  # pressures, the 3 segments' coordinates, velocities, energy
    for v in views:  # no legend over the data; the whole run on the time axis
        assert "visible=[False]" in repr(v.properties["PlotLegend"])
        assert "250000000" in repr(v.properties["TimeAxis"]) or "0.25" in repr(v.properties["TimeAxis"])


def test_rerun_mcap_importer_shows_the_frames_and_the_backbone(tmp_path):
    """What `rerun recording.mcap` draws, measured with Rerun's own importer (`rerun mcap
    convert`): the frame tree from /qchain/tf (Transform3D, world -> base -> tips) and the
    backbone from /qchain/backbone_points (Points3D). Its Foxglove decoder does not take
    SceneUpdate (the line strips) nor qchain's JSON state (no plots): `qchain replay` is the
    full view."""
    import rerun as rr

    records = arm_records(30, dt=0.01)
    path = tmp_path / "run.mcap"
    with RunLogger(arm_info(), path, quiet=True) as log:
        for r in records:
            log.log(r)
    out = tmp_path / "imported.rrd"
    subprocess.run([rerun_cli(), "mcap", "convert", str(path), "-o", str(out), "--timeline-type", "duration"],
                   check=True, capture_output=True, timeout=120)
    comps: dict[str, set] = {}
    points, frames = [], []
    for chunk in rr.chunk.RrdReader(out).stream():
        rb = chunk.to_record_batch()
        comps.setdefault(chunk.entity_path, set()).update(rb.schema.names)
        if chunk.entity_path == TOPICS["points"] and "Points3D:positions" in rb.schema.names:
            points += rb.column(rb.schema.names.index("Points3D:positions")).to_pylist()
        if chunk.entity_path == TOPICS["tf"] and "Transform3D:child_frame" in rb.schema.names:
            frames += rb.column(rb.schema.names.index("Transform3D:child_frame")).to_pylist()
    assert "Transform3D:parent_frame" in comps[TOPICS["tf"]]
    assert {"base", "segment_1_tip", "segment_3_tip"} <= {f for row in frames for f in (row or [])}
    assert len(points) == 30
    np.testing.assert_allclose(np.array(points[-1]), records[-1].backbone.reshape(-1, 3), rtol=1e-6)
    assert not any(c.startswith(("LineStrips3D", "Scalars")) for cs in comps.values() for c in cs)


def test_the_foxglove_layout_names_every_series():
    info = RunInfo(n_segments=2, radii=[0.01, 0.01], q_names=["segment 1 l [m]", "segment 1 ux [1/m]",
                                                               "segment 1 uy [1/m]", "segment 2 l [m]",
                                                               "segment 2 ux [1/m]", "segment 2 uy [1/m]"],
                   params={"segments": [{"length": 0.1}, {"length": 0.1}]})
    layout = json.loads(foxglove_layout(info, 6, 6, 6).to_json())
    text = json.dumps(layout)
    assert '"label":"segment 2 ux [1/m]"'.replace(":", ": ") in text or '"label": "segment 2 ux [1/m]"' in text
    assert "/qchain/state.q[4]" in text and '"followTf": "base"' in text
    assert '"legendDisplay": "top"' in text  # above the plot, not over the data


def test_rerun_draws_the_tendon_paths_and_plots_the_tensions(tmp_path):
    """A run with tendons in the .rrd: ``/arm/tendons`` holds, at each record, one line strip
    a tendon, its finite points only (a tendon ending mid-arm is shorter), equal to the
    recorded paths; ``/plots/tension`` the tensions, named by tendon."""
    import dataclasses

    import rerun as rr

    records = arm_records(8)
    P = records[0].backbone.shape[1]
    rng = np.random.default_rng(3)
    paths = rng.normal(size=(8, 2, 3 * P, 3))
    paths[:, 0, P:] = np.nan  # tendon 0 ends at the first segment's tip
    tension = rng.uniform(0.0, 5.0, size=(8, 2))
    rrd = tmp_path / "run.rrd"
    with RunLogger(arm_info(), io.BytesIO(), rrd=rrd, quiet=True) as log:
        for k, r in enumerate(records):
            log.log(dataclasses.replace(r, tension=tension[k], tendons=paths[k]))
    strips, scalars, names = [], [], None
    for chunk in rr.chunk.RrdReader(rrd).stream():
        rb = chunk.to_record_batch()
        cols = rb.schema.names
        if chunk.entity_path == "/arm/tendons" and "LineStrips3D:strips" in cols:
            strips += rb.column(cols.index("LineStrips3D:strips")).to_pylist()
        if chunk.entity_path == "/plots/tension":
            if "Scalars:scalars" in cols:
                scalars += rb.column(cols.index("Scalars:scalars")).to_pylist()
            if "SeriesLines:names" in cols:
                names = rb.column(cols.index("SeriesLines:names")).to_pylist()[0]
    assert len(strips) == 8 and all(len(s) == 2 for s in strips)
    for k, (short, full) in enumerate(strips):
        assert np.array(short).shape == (P, 3) and np.array(full).shape == (3 * P, 3)
        np.testing.assert_allclose(np.array(short), paths[k, 0, :P], rtol=1e-6)
        np.testing.assert_allclose(np.array(full), paths[k, 1], rtol=1e-6)
    np.testing.assert_allclose(np.array(scalars), tension)
    assert names == ["tendon 0 [N]", "tendon 1 [N]"]
