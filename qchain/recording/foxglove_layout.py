"""The Foxglove layout qchain ships, built with ``foxglove-sdk``'s layout types
(docs/recording.md, "The viewers"); ``qchain layout RECORDING.mcap -o layout.json`` writes it."""

from __future__ import annotations

import json

from .records import CONTACT_TOPICS, TOPICS, RunInfo

__all__ = ["foxglove_layout", "layout_json"]


def _plot(fl, title: str, values: list[tuple[str, str]]):
    return fl.PlotPanel(title=title, config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=v, label=label, enabled=True, timestamp_method="receiveTime")
               for v, label in values],
        show_legend=True, legend_display="top", show_x_axis_labels=True, show_y_axis_labels=True,
        is_synced=True, x_axis_val="timestamp", time_range="all", time_window_mode="automatic"))


def foxglove_layout(info: RunInfo, nq: int, nv: int, n_p: int):
    """The :class:`foxglove.layouts.Layout` of a run with ``nq`` coordinates, ``nv``
    velocities and ``n_p`` pressures."""
    import foxglove.layouts as fl

    st = TOPICS["state"]
    n = info.n_segments
    qn = info.names("q", nq)
    s0 = max(0, nq - 3 * n)

    def tab(title: str, what: str, key: str, names: list[str], idx):
        return fl.TabItem(title=title, content=_plot(fl, what, [(f"{st}.{key}[{j}]", names[j]) for j in idx]))

    q_tabs = [tab("base", "base coordinates", "q", qn, range(s0))] if s0 else []
    q_tabs += [tab(f"segment {i + 1}", f"segment {i + 1} coordinates", "q", qn,
                   range(s0 + 3 * i, min(s0 + 3 * i + 3, nq))) for i in range(n)]
    q_tabs.append(tab("velocities", "velocities", "v", info.names("v", nv), range(nv)))
    pn = info.names("p", n_p)
    pressures = _plot(fl, "chamber pressures [Pa]", [(f"{st}.p[{j}]", pn[j]) for j in range(n_p)])
    energy = _plot(fl, "energy [J]", [(f"{st}.{k}", f"{k} [J]") for k in ("kinetic", "potential", "total")])
    reach = sum(float(s.get("length", 0.0)) for s in info.params.get("segments", [])
                if isinstance(s, dict)) or 10.0 * sum(info.radii)
    topics = {TOPICS["arm"]: fl.BaseRendererSceneUpdateTopicSettings(visible=True),
              TOPICS["points"]: fl.BaseRendererPointCloudTopicSettings(visible=False)}
    if info.records_contacts:  # the obstacles and the contact forces, drawn with the arm
        topics.update({CONTACT_TOPICS[k]: fl.BaseRendererSceneUpdateTopicSettings(visible=True)
                       for k in ("obstacles", "forces")})
    three = fl.ThreeDeePanel(title="arm", config=fl.ThreeDeeConfig(
        follow_tf="base", follow_mode="follow-position",
        camera_state=fl.ThreeDeeCameraState(distance=4.0 * reach, perspective=True, phi=70.0, theta_offset=35.0,
                                            target_offset=(0.0, 0.0, 0.5 * reach), fovy=45.0, near=0.001,
                                            far=1000.0),
        topics=topics,
    ))
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=3, content=three),
        fl.SplitItem(proportion=2, content=fl.SplitContainer(direction="column", items=[
            fl.SplitItem(proportion=1, content=pressures),
            fl.SplitItem(proportion=1, content=fl.TabContainer(tabs=q_tabs)),
            fl.SplitItem(proportion=1, content=energy),
        ])),
    ]))


def layout_json(info: RunInfo, nq: int, nv: int, n_p: int) -> str:
    """The layout as the JSON text Foxglove imports."""
    return json.dumps(json.loads(foxglove_layout(info, nq, nv, n_p).to_json()), indent=1)
