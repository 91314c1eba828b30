"""A recording as a ROS 2 bag: an MCAP file of the ``ros2`` profile whose messages are CDR
encoded ROS 2 messages, for ``ros2 bag play``, Foxglove (natively) and any ROS 2 tool.

qchain's own recording keeps its JSON and Foxglove channels (what :func:`read_recording`
reads back bit for bit); a ROS 2 bag is written beside it, from the finished recording
(:func:`export_ros2`, ``qchain export``, ``qchain run --ros2 OUT``), so a run killed before
the end loses nothing here either: recover the recording, then export it.

Topics (every message stamped with the simulation time; the MCAP log time the same, ns):

``/tf``                     ``tf2_msgs/msg/TFMessage``: the frame tree ``world`` -> ``base``
                            -> ``segment_1_tip`` -> ... -> ``segment_n_tip``, each transform
                            the child's placement in its parent (m; unit quaternion).
``/joint_states``           ``sensor_msgs/msg/JointState``: the segments' coordinates
                            (``position``: ``l`` in m, curvatures ``ux``, ``uy`` in 1/m, or the
                            paper's ``psi`` rad, ``kappa`` 1/m) and their rates (``velocity``),
                            named ``segment_<i>_<coordinate>``; a floating base is in ``/tf``.
``/qchain/pressures``       ``sensor_msgs/msg/JointState``: the chamber pressures in
                            ``effort``, Pa, named ``segment_<i>_chamber_<j>``.
``/qchain/markers``         ``visualization_msgs/msg/MarkerArray``: the backbone of each
                            segment (a ``LINE_STRIP``, width the segment's diameter) and the
                            obstacles (``CUBE``, ``SPHERE``, ``CYLINDER``; a capsule as a
                            cylinder and two spheres) in ``world``, every sample.

The message definitions are the ROS 2 Humble ones (from ``rosbags``' type store); the
messages are encoded by ``mcap-ros2-support``. The run's description (the sealed ``qchain``
metadata of the recording) is copied into the bag's metadata.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .records import SEGMENT_COLORS, Batch, RunInfo
from .scenery import OBSTACLE_COLOR, motion_offset, obstacle_shapes
from .scenery import reach as arm_reach

__all__ = ["ROS2_TOPICS", "BagWriter", "stamp", "write_ros2", "export_ros2", "joint_names", "pressure_names"]

#: topic -> ROS 2 message type of a qchain ROS 2 bag
ROS2_TOPICS = {
    "/tf": "tf2_msgs/msg/TFMessage",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/qchain/pressures": "sensor_msgs/msg/JointState",
    "/qchain/markers": "visualization_msgs/msg/MarkerArray",
}

# visualization_msgs/Marker types and actions
_ARROW, _CUBE, _SPHERE, _CYLINDER, _LINE_STRIP = 0, 1, 2, 3, 4
_ADD = 0


def _msgdef(typename: str) -> tuple[str, str]:
    """The ``ros2msg`` schema (name, text with every dependency) of a ROS 2 message type."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    text, _ = store.generate_msgdef(typename, ros_version=2)
    pkg, _, name = typename.split("/")
    return f"{pkg}/msg/{name}", text


def joint_names(info: RunInfo) -> list[str]:
    """The ROS names of the segments' coordinates, ``segment_<i>_<coordinate>`` (3 n)."""
    n = info.n_segments
    names = list(info.q_names or ())[-3 * n:]
    out = []
    for k in range(3 * n):
        i, j = divmod(k, 3)
        parts = names[k].split() if len(names) == 3 * n else []
        coord = parts[2] if len(parts) >= 3 and parts[0] == "segment" else f"q{j}"
        out.append(f"segment_{i + 1}_{coord}")
    return out


def pressure_names(info: RunInfo, n_pressures: int) -> list[str]:
    """``segment_<i>_chamber_<j>`` for the ``n_pressures`` pressures (3 a segment)."""
    return [f"segment_{k // 3 + 1}_chamber_{k % 3 + 1}" for k in range(n_pressures)]


def _color(rgb, a: float = 1.0) -> dict:
    return {"r": rgb[0] / 255.0, "g": rgb[1] / 255.0, "b": rgb[2] / 255.0, "a": a}


def _pose(p, quat) -> dict:
    return {"position": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "orientation": {"x": float(quat[0]), "y": float(quat[1]), "z": float(quat[2]), "w": float(quat[3])}}


def _obstacle_markers(info: RunInfo, shapes, offsets: np.ndarray, header: dict) -> list[dict]:
    """The obstacles as markers, each translated by ``offsets[i]`` (m, 3) m."""
    color = _color(OBSTACLE_COLOR, 0.5)
    out = []
    for sh in shapes:
        u = offsets[sh.index]
        c = sh.center + u
        base = {"header": header, "ns": "obstacles", "action": _ADD, "color": color, "frame_locked": False}
        kind = {"box": _CUBE, "sphere": _SPHERE}.get(sh.kind, _CYLINDER)
        out.append({**base, "id": 3 * sh.index, "type": kind, "pose": _pose(c, sh.quaternion),
                    "scale": {"x": float(sh.size[0]), "y": float(sh.size[1]), "z": float(sh.size[2])}})
        if sh.kind == "capsule":  # a capsule is its cylinder and two balls at its ends
            ob = info.obstacles[sh.index]
            d = float(sh.size[0])
            for e, end in enumerate((ob["a"], ob["b"])):
                p = np.asarray(end, dtype=float) + u
                out.append({**base, "id": 3 * sh.index + 1 + e, "type": _SPHERE, "pose": _pose(p, (0, 0, 0, 1)),
                            "scale": {"x": d, "y": d, "z": d}})
    return out


class BagWriter:
    """A ROS 2 bag being written: an MCAP file of the ``ros2`` profile (``mcap-ros2-support``'s
    writer), each message type's schema the ROS 2 Humble definition (``rosbags``' type store),
    registered at its first message.

    Parameters
    ----------
    out : binary stream
        Where the MCAP goes (written from its start; not closed).
    metadata : dict, optional
        Entries of the bag's ``qchain`` metadata record.
    """

    def __init__(self, out, *, metadata: dict[str, str] | None = None):
        from mcap_ros2.writer import Writer

        self._w = Writer(out)
        self._schemas: dict[str, object] = {}
        self.count = 0
        if metadata:
            self._w.add_metadata("qchain", dict(metadata))

    def write(self, topic: str, typename: str, t: float | int, message: dict, sequence: int = 0) -> None:
        """One message (a dict of the type's fields; missing ones take their defaults) of ROS 2
        type ``typename`` (e.g. ``"geometry_msgs/msg/PoseStamped"``) on ``topic`` at log time
        ``t`` (an int: ns; a float: s)."""
        schema = self._schemas.get(typename)
        if schema is None:
            schema = self._schemas[typename] = self._w.register_msgdef(*_msgdef(typename))
        lt = t if isinstance(t, int) else int(round(float(t) * 1e9))
        self._w.write_message(topic, schema, message, log_time=lt, publish_time=lt, sequence=sequence)
        self.count += 1

    def finish(self) -> int:
        """Write the summary; returns the number of messages."""
        self._w.finish()
        return self.count


def stamp(t: float | int) -> dict:
    """A ``builtin_interfaces/Time`` of ``t`` (an int: ns; a float: s)."""
    lt = t if isinstance(t, int) else int(round(float(t) * 1e9))
    return {"sec": lt // 1_000_000_000, "nanosec": lt % 1_000_000_000}


def write_ros2(b: Batch, info: RunInfo, out, *, metadata: dict[str, str] | None = None) -> int:
    """Write the records ``b`` of a run described by ``info`` as a ROS 2 bag (the topics of
    :data:`ROS2_TOPICS`).

    Parameters
    ----------
    b : Batch
        The records (a :class:`~qchain.logging.Recording` is one), K of them.
    info : RunInfo
    out : binary stream
        Where the MCAP goes (written from its start; not closed).
    metadata : dict, optional
        Entries of the bag's ``qchain`` metadata record.

    Returns
    -------
    int
        The number of messages written.
    """
    from .mcap_sink import relative_frames

    w = BagWriter(out, metadata=metadata)
    K = len(b)
    n = info.n_segments
    jnames = joint_names(info)
    pnames = pressure_names(info, b.p.shape[1])
    frames = ["world", "base"] + [f"segment_{i + 1}_tip" for i in range(n)]
    colors = [_color(SEGMENT_COLORS[i % len(SEGMENT_COLORS)]) for i in range(n)]
    shapes, moving = [], []
    if info.obstacles and K:
        shapes = obstacle_shapes(info.obstacles, 2.0 * arm_reach(info, b.backbone[0]))
        moving = [sh.index for sh in shapes if info.obstacles[sh.index].get("motion") is not None]
    offsets = np.zeros((K, len(info.obstacles or ()), 3))
    for i in moving:
        offsets[:, i] = motion_offset(info.obstacles[i]["motion"], b.t)
    rel = relative_frames(b.base, b.tip_frames) if K else np.zeros((0, n + 1, 7))
    lts = np.rint(b.t * 1e9).astype(np.int64).tolist()
    for k in range(K):
        lt = lts[k]
        seq = int(b.step[k]) & 0xFFFFFFFF
        st = stamp(lt)
        world = {"stamp": st, "frame_id": "world"}
        tf = {"transforms": [
            {"header": {"stamp": st, "frame_id": frames[j]}, "child_frame_id": frames[j + 1],
             "transform": {"translation": {"x": f[0], "y": f[1], "z": f[2]},
                           "rotation": {"x": f[3], "y": f[4], "z": f[5], "w": f[6]}}}
            for j, f in enumerate(rel[k].tolist())]}
        joints = {"header": {"stamp": st, "frame_id": ""}, "name": jnames,
                  "position": b.q[k, -3 * n:].tolist(), "velocity": b.v[k, -3 * n:].tolist(), "effort": []}
        pressures = {"header": {"stamp": st, "frame_id": ""}, "name": pnames, "position": [], "velocity": [],
                     "effort": b.p[k].tolist()}
        markers = [{"header": world, "ns": "backbone", "id": i, "type": _LINE_STRIP, "action": _ADD,
                    "pose": _pose((0, 0, 0), (0, 0, 0, 1)),
                    "scale": {"x": 2.0 * float(info.radii[i]), "y": 0.0, "z": 0.0}, "color": colors[i],
                    "frame_locked": False,
                    "points": [{"x": x, "y": y, "z": z} for x, y, z in b.backbone[k, i].tolist()]}
                   for i in range(n)]
        markers += _obstacle_markers(info, shapes, offsets[k], world)
        for topic, msg in (("/tf", tf), ("/joint_states", joints), ("/qchain/pressures", pressures),
                           ("/qchain/markers", {"markers": markers})):
            w.write(topic, ROS2_TOPICS[topic], lt, msg, sequence=seq)
    return w.finish()


def export_ros2(recording: str | os.PathLike, out: str | os.PathLike, *, limits=None) -> int:
    """Write the qchain recording ``recording`` as the ROS 2 bag ``out`` (an ``.mcap`` file).

    The bag is written to a temporary file beside ``out`` and moved into place when complete:
    ``out`` is either the whole bag or untouched.

    Parameters
    ----------
    recording : path
        A qchain recording (``.mcap``); a killed run's is read with its journal.
    out : path
        The bag to write; must end in ``.mcap`` and not be ``recording``.
    limits : qchain.logging.ReadLimits, optional

    Returns
    -------
    int
        The number of messages written.

    Raises
    ------
    ValueError
        ``out`` does not end in ``.mcap`` or is the recording.
    qchain.logging.RecordingFormatError, qchain.logging.LoggingError
        The recording cannot be read.
    """
    from ..checks.paths import written_whole
    from .reader import read_recording

    out = Path(out)
    if out.suffix != ".mcap":
        raise ValueError(f"out must be an .mcap file (a ROS 2 bag in MCAP storage), got {str(out)!r}")
    if out.exists() and Path(recording).exists() and os.path.samefile(out, recording):
        raise ValueError(f"out is the recording itself ({str(out)!r}): choose another path")
    rec = read_recording(recording, limits=limits)
    meta = dict(rec.metadata)  # the recording's sealed description, as it is
    with written_whole(out, binary=True, prefix=".ros2-") as fh:
        count = write_ros2(rec, rec.info, fh, metadata=meta)
    return count
