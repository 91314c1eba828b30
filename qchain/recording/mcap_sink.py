"""The recording: an MCAP file written with the mcap library's ``Writer``.

Its channels, chunks and metadata are described in docs/recording.md, "The file": the Foxglove
messages are built by ``foxglove-sdk``, ``/qchain/state`` is JSON in shortest round-trip form
(``null`` for a non-finite number), chunks close at step boundaries."""

from __future__ import annotations

import datetime as _dt
import json
import os
import time
from contextlib import suppress
from typing import BinaryIO

import numpy as np

from .records import (
    CONTACT_TOPICS,
    FORMAT_NAME,
    FORMAT_VERSION,
    SEGMENT_COLORS,
    TOPICS,
    Batch,
    RunInfo,
    ns,
    seal,
)
from .scenery import (
    CONTACT_COLOR,
    OBSTACLE_COLOR,
    TENDON_COLOR,
    force_scale,
    motion_offset,
    obstacle_shapes,
    quat_between,
    quat_mul,
    quat_rotate,
)
from .scenery import reach as arm_reach

__all__ = ["McapSink", "info_metadata", "STATE_SCHEMA", "CONTACTS_SCHEMA", "relative_frames"]

#: JSON schema of ``/qchain/state`` (a number may be null: a non-finite value).
STATE_SCHEMA = {
    "title": "qchain.State",
    "description": "The arm at one output sample of a qchain run",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "simulation time, s"},
        "step": {"type": "integer", "description": "sample counter"},
        "q": {"type": "array", "items": {"type": "number"}, "description": "generalised coordinates"},
        "v": {"type": "array", "items": {"type": "number"}, "description": "velocities"},
        "p": {"type": "array", "items": {"type": "number"}, "description": "chamber pressures, Pa"},
        "kinetic": {"type": "number", "description": "kinetic energy, J"},
        "potential": {"type": "number", "description": "potential energy (gravity + elastic), J"},
        "total": {"type": "number", "description": "kinetic + potential, J"},
        "base": {"type": "array", "items": {"type": "number"},
                 "description": "world placement of the base: x, y, z (m), qx, qy, qz, qw"},
        "tips": {"type": "array", "items": {"type": "array", "items": {"type": "number"}},
                 "description": "world placement of each segment tip: x, y, z (m), qx, qy, qz, qw"},
        "backbone": {"type": "array",
                     "items": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}},
                     "description": "world backbone points of each segment, root to tip, m"},
        "tension": {"type": "array", "items": {"type": "number"},
                    "description": "the tendons' tensions, N (a run with tendons only)"},
    },
    "required": ["t", "step", "q", "v", "p", "kinetic", "potential", "total", "base", "tips", "backbone"],
}


_VEC3S = {"type": "array", "items": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}}

#: JSON schema of ``/qchain/contacts``: one sample's active contacts, ``c`` of them.
CONTACTS_SCHEMA = {
    "title": "qchain.Contacts",
    "description": "The active contacts of the arm at one output sample of a qchain run",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "simulation time, s"},
        "step": {"type": "integer", "description": "sample counter (that of /qchain/state)"},
        "point": {**_VEC3S, "description": "contact points on the arm's surface, world frame, m"},
        "normal": {**_VEC3S, "description": "the obstacles' outward unit normals there, world frame"},
        "force": {**_VEC3S, "description": "the forces on the arm, world frame, N"},
        "segment": {"type": "array", "items": {"type": "integer"}, "description": "the segment touching (0-based)"},
        "obstacle": {"type": "array", "items": {"type": "integer"},
                     "description": "index into the obstacles of the qchain metadata's info"},
    },
    "required": ["t", "step", "point", "normal", "force", "segment", "obstacle"],
}


def info_metadata(info: RunInfo, recording_id: str) -> dict[str, str]:
    """The ``qchain`` metadata entries of a recording (sealed by the writers)."""
    return {
        "format": FORMAT_NAME,
        "format_version": str(FORMAT_VERSION),
        "qchain_version": info.qchain_version,
        "scene": info.scene,
        "scene_path": info.scene_path or "",
        "params": json.dumps(info.params, sort_keys=True),
        "n_segments": str(info.n_segments),
        "radii": json.dumps(list(info.radii)),
        "recording_id": recording_id,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "info": json.dumps(info.to_json(), sort_keys=True),
        "topics": json.dumps(TOPICS, sort_keys=True),
    }


def relative_frames(base: np.ndarray, tips: np.ndarray) -> np.ndarray:
    """The frame tree's transforms (K, n + 1, 7): world -> base, base -> tip 1, tip i -> tip
    i + 1, each as its child's placement in its parent (x, y, z, qx, qy, qz, qw), from
    world placements ``base`` (K, 7) and ``tips`` (K, n, 7)."""
    world = np.concatenate([base[:, None, :], tips], axis=1)  # (K, n + 1, 7)
    out = world.copy()
    parent = world[:, :-1]
    child = world[:, 1:]
    pinv = parent[..., 3:] * np.array([-1.0, -1.0, -1.0, 1.0])  # conjugate = inverse of a unit quaternion
    with np.errstate(all="ignore"):  # a non-finite record gives non-finite transforms, said as such
        out[:, 1:, :3] = quat_rotate(pinv, child[..., :3] - parent[..., :3])
        out[:, 1:, 3:] = quat_mul(pinv, child[..., 3:])
    return out


class McapSink:
    """Writes batches of records into an MCAP file or binary stream.

    Parameters
    ----------
    out : path or binary stream
    info : RunInfo
    recording_id : str
    flush_interval, flush_wall_interval : float, s
        Simulation and wall time between chunk flushes.
    """

    def __init__(self, out: str | os.PathLike | BinaryIO, info: RunInfo, *, recording_id: str,
                 flush_interval: float, flush_wall_interval: float):
        import foxglove.messages as fm
        import orjson
        from mcap.writer import CompressionType, Writer

        self._fm = fm
        self._dumps = orjson.dumps
        self._opt = orjson.OPT_SERIALIZE_NUMPY
        self.info = info
        self._owns = isinstance(out, (str, os.PathLike))  # a file this sink opens (and closes)
        self.path: str | None = os.fspath(out) if self._owns else None
        self._stream = open(self.path, "wb") if self._owns else out
        # chunks are cut here, at step boundaries (flush), never by size inside a step
        self._w = Writer(self._stream, chunk_size=1 << 40, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=f"qchain {info.qchain_version}")
        ch = {}  # (the schema and channel records go into the first chunk)
        sid = self._w.register_schema("qchain.State", "jsonschema", json.dumps(STATE_SCHEMA).encode())
        ch["state"] = self._w.register_channel(TOPICS["state"], "json", sid)
        for key, cls in (("tf", fm.FrameTransforms), ("arm", fm.SceneUpdate), ("points", fm.PointCloud)):
            s = cls.get_schema()
            ch[key] = self._w.register_channel(TOPICS[key], "protobuf",
                                               self._w.register_schema(s.name, s.encoding, s.data))
        if info.records_contacts:
            sid = self._w.register_schema("qchain.Contacts", "jsonschema", json.dumps(CONTACTS_SCHEMA).encode())
            ch["contacts"] = self._w.register_channel(CONTACT_TOPICS["contacts"], "json", sid)
            s = fm.SceneUpdate.get_schema()
            sid = self._w.register_schema(s.name, s.encoding, s.data)
            for key in ("forces", "obstacles"):
                ch[key] = self._w.register_channel(CONTACT_TOPICS[key], "protobuf", sid)
        self._ch = ch
        topics = {**TOPICS, **CONTACT_TOPICS}
        # the channel ids in the sealed metadata too: a damaged first chunk loses its channel
        # records, not the meaning of every chunk after it
        meta = info_metadata(info, recording_id)
        meta["channels"] = json.dumps({str(cid): topics[key] for key, cid in ch.items()}, sort_keys=True)
        self._meta = seal(meta)
        self._w.add_metadata("qchain", self._meta)
        self.flush_interval = float(flush_interval)
        self.flush_wall_interval = float(flush_wall_interval)
        self._last_flush_t: float | None = None
        self._last_flush_wall = time.monotonic()
        self._open = 0  # records in the open chunk
        self._static = None
        self._obstacles: tuple[list, list[int]] = ([], [])  # their shapes, the moving ones (_obstacle_parts)
        self.n_records = 0
        self.last_t: float | None = None
        self.finished = False

    def _statics(self, n: int):
        fm = self._fm
        colors = [fm.Color(r=c[0] / 255.0, g=c[1] / 255.0, b=c[2] / 255.0, a=1.0)
                  for c in (SEGMENT_COLORS[i % len(SEGMENT_COLORS)] for i in range(n))]
        names = ["world", "base"] + [f"segment_{i + 1}_tip" for i in range(n)]
        F64 = fm.PackedElementFieldNumericType.Float64
        fields = [fm.PackedElementField(name=c, offset=8 * i, type=F64) for i, c in enumerate("xyz")]
        identity = fm.Pose(position=fm.Vector3(x=0.0, y=0.0, z=0.0),
                           orientation=fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
        return colors, names, fields, identity

    def flush(self) -> None:
        """Close the open chunk (compressed, handed to the operating system)."""
        self._w.flush()
        self._open = 0
        self._last_flush_wall = time.monotonic()

    def write_batch(self, b: Batch) -> None:
        K = len(b)
        if K == 0:
            return
        fm = self._fm
        n = b.backbone.shape[1]
        if self._static is None:
            self._static = self._statics(n)
            self._scale = force_scale(arm_reach(self.info, b.backbone[0]), self.info.force_ref)
            if "obstacles" in self._ch:
                self._obstacles = self._obstacle_parts(b)
                if not self._obstacles[1]:  # none moves: one message for the whole run
                    lt = ns(float(b.t[0]))
                    self._write_obstacles(lt, 0, np.zeros((len(self.info.obstacles or ()), 3)))
        colors, names, fields, identity = self._static
        dumps, opt, w, ch = self._dumps, self._opt, self._w, self._ch
        ns_all = np.rint(b.t * 1e9).astype(np.int64)
        if K and ns_all.min() < 0:
            raise ValueError("negative simulation time")
        rel = relative_frames(b.base, b.tip_frames).tolist()
        ts, steps, lts = b.t.tolist(), b.step.tolist(), ns_all.tolist()
        radii = self.info.radii
        last_flush_t = self._last_flush_t
        moved = self._obstacle_offsets(b) if "obstacles" in ch and self._obstacles[1] else None
        for k in range(K):
            t, step, lt = ts[k], steps[k], lts[k]
            seq = step & 0xFFFFFFFF
            fields_k = {"t": b.t[k], "step": step, "q": b.q[k], "v": b.v[k], "p": b.p[k],
                        "kinetic": b.energy[k, 0], "potential": b.energy[k, 1], "total": b.energy[k, 2],
                        "base": b.base[k], "tips": b.tip_frames[k], "backbone": b.backbone[k]}
            if b.tension is not None:  # (a run without tendons writes the state as before)
                fields_k["tension"] = b.tension[k]
            state = dumps(fields_k, option=opt)
            stamp = fm.Timestamp(lt // 1_000_000_000, lt % 1_000_000_000)
            tf = fm.FrameTransforms(transforms=[
                fm.FrameTransform(timestamp=stamp, parent_frame_id=names[j], child_frame_id=names[j + 1],
                                  translation=fm.Vector3(x=f[0], y=f[1], z=f[2]),
                                  rotation=fm.Quaternion(x=f[3], y=f[4], z=f[5], w=f[6]))
                for j, f in enumerate(rel[k])])
            bb = b.backbone[k]
            arm = fm.SceneUpdate(entities=[
                fm.SceneEntity(timestamp=stamp, frame_id="world", id=f"segment_{i + 1}", lines=[fm.LinePrimitive(
                    type=fm.LinePrimitiveLineType.LineStrip, thickness=2.0 * radii[i], scale_invariant=False,
                    points=[fm.Point3(x=x, y=y, z=z) for x, y, z in bb[i].tolist()], color=colors[i],
                    pose=identity)])
                for i in range(n)] + self._tendon_entities(b, k, stamp, identity))
            pts = fm.PointCloud(timestamp=stamp, frame_id="world", pose=identity, point_stride=24, fields=fields,
                                data=np.ascontiguousarray(bb).tobytes())
            w.add_message(ch["state"], lt, state, lt, seq)
            w.add_message(ch["tf"], lt, tf.encode(), lt, seq)
            w.add_message(ch["arm"], lt, arm.encode(), lt, seq)
            w.add_message(ch["points"], lt, pts.encode(), lt, seq)
            if "contacts" in ch:
                self._write_contacts(b, k, lt, seq, stamp)
            if moved is not None:
                self._write_obstacles(lt, seq, moved[k])
            self._open += 1
            if last_flush_t is None:
                last_flush_t = t
            if t - last_flush_t >= self.flush_interval:
                self.flush()
                last_flush_t = t
        self._last_flush_t = last_flush_t
        self.n_records += K
        self.last_t = ts[-1]
        self.tick()

    def _tendon_entities(self, b: Batch, k: int, stamp, identity) -> list:
        """Record ``k``'s tendon paths as thin line strips (none without them)."""
        if b.tendons is None:
            return []
        fm = self._fm
        thin = 0.2 * min(self.info.radii)
        color = fm.Color(r=TENDON_COLOR[0] / 255.0, g=TENDON_COLOR[1] / 255.0, b=TENDON_COLOR[2] / 255.0, a=1.0)
        out = []
        for i, path in enumerate(b.tendons[k]):
            path = path[np.isfinite(path).all(axis=1)]
            out.append(fm.SceneEntity(timestamp=stamp, frame_id="world", id=f"tendon_{i}", lines=[fm.LinePrimitive(
                type=fm.LinePrimitiveLineType.LineStrip, thickness=thin, scale_invariant=False,
                points=[fm.Point3(x=x, y=y, z=z) for x, y, z in path.tolist()], color=color, pose=identity)]))
        return out

    def _obstacle_parts(self, b: Batch):
        """The obstacles' shapes at ``t = 0`` (:func:`obstacle_shapes`, sized by the first
        record's reach) and the indices of those that move."""
        shapes = obstacle_shapes(self.info.obstacles, 2.0 * arm_reach(self.info, b.backbone[0]))
        return shapes, [sh.index for sh in shapes if self.info.obstacles[sh.index].get("motion") is not None]

    def _obstacle_offsets(self, b: Batch) -> np.ndarray:
        """Every obstacle's translation from ``t = 0`` (K, m, 3) m at the batch's records (zeros
        for a fixed one), by its law in ``RunInfo.obstacles`` (:func:`motion_offset`)."""
        out = np.zeros((len(b), len(self.info.obstacles or ()), 3))
        for i in self._obstacles[1]:
            out[:, i] = motion_offset(self.info.obstacles[i]["motion"], b.t)
        return out

    def _write_obstacles(self, lt: int, seq: int, offsets: np.ndarray) -> None:
        """All the obstacles, lifetime 0, each translated by ``offsets[i]`` (m, 3) m, at the
        time ``lt`` ns. Without a moving obstacle this is one message at the first record's
        time; with one, a message each record holding them all: Foxglove shows, after a seek,
        the last message of a topic before the time sought, so each message draws the whole
        scene where it is then (a frame-locked entity on a moving frame would depend on the
        transforms around the time instead)."""
        fm = self._fm
        stamp = fm.Timestamp(lt // 1_000_000_000, lt % 1_000_000_000)
        color = fm.Color(r=OBSTACLE_COLOR[0] / 255.0, g=OBSTACLE_COLOR[1] / 255.0, b=OBSTACLE_COLOR[2] / 255.0,
                         a=0.5)
        unturned = fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
        entities = []
        for sh in self._obstacles[0]:
            i, u = sh.index, offsets[sh.index]
            c = sh.center + u
            pose = fm.Pose(position=fm.Vector3(x=c[0], y=c[1], z=c[2]),
                           orientation=fm.Quaternion(x=sh.quaternion[0], y=sh.quaternion[1], z=sh.quaternion[2],
                                                     w=sh.quaternion[3]))
            size = fm.Vector3(x=sh.size[0], y=sh.size[1], z=sh.size[2])
            prim = {}
            if sh.kind == "box":
                prim["cubes"] = [fm.CubePrimitive(pose=pose, size=size, color=color)]
            elif sh.kind == "sphere":
                prim["spheres"] = [fm.SpherePrimitive(pose=pose, size=size, color=color)]
            else:  # a cylinder; a capsule is its cylinder and two balls at its ends
                prim["cylinders"] = [fm.CylinderPrimitive(pose=pose, size=size, bottom_scale=1.0, top_scale=1.0,
                                                          color=color)]
                if sh.kind == "capsule":
                    ob = self.info.obstacles[i]
                    ball = fm.Vector3(x=sh.size[0], y=sh.size[0], z=sh.size[0])
                    ends = (np.asarray(ob["a"], dtype=float) + u, np.asarray(ob["b"], dtype=float) + u)
                    prim["spheres"] = [fm.SpherePrimitive(pose=fm.Pose(position=fm.Vector3(x=e[0], y=e[1], z=e[2]),
                                                                       orientation=unturned),
                                                          size=ball, color=color) for e in ends]
            entities.append(fm.SceneEntity(timestamp=stamp, frame_id="world", id=f"obstacle_{i}", **prim))
        self._w.add_message(self._ch["obstacles"], lt, fm.SceneUpdate(entities=entities).encode(), lt, seq)

    def _write_contacts(self, b: Batch, k: int, lt: int, seq: int, stamp) -> None:
        """Record ``k``'s contacts: the JSON message and the force arrows at the points."""
        fm = self._fm
        c = b.contact_set(k)
        self._w.add_message(self._ch["contacts"], lt, self._dumps(
            {"t": b.t[k], "step": int(b.step[k]), "point": c.point, "normal": c.normal, "force": c.force,
             "segment": c.segment, "obstacle": c.obstacle}, option=self._opt), lt, seq)
        color = fm.Color(r=CONTACT_COLOR[0] / 255.0, g=CONTACT_COLOR[1] / 255.0, b=CONTACT_COLOR[2] / 255.0, a=1.0)
        radii = self.info.radii
        arrows = []
        for x, f, seg in zip(c.point.tolist(), c.force, c.segment.tolist()):
            length = float(np.linalg.norm(f)) * self._scale
            if not length > 0.0:
                continue
            d = 0.3 * radii[min(max(seg, 0), len(radii) - 1)]  # the shaft a third of the tube's radius thick
            qr = quat_between([1.0, 0.0, 0.0], f)  # an arrow points along its pose's x axis
            arrows.append(fm.ArrowPrimitive(
                pose=fm.Pose(position=fm.Vector3(x=x[0], y=x[1], z=x[2]),
                             orientation=fm.Quaternion(x=qr[0], y=qr[1], z=qr[2], w=qr[3])),
                shaft_length=0.75 * length, shaft_diameter=d, head_length=0.25 * length, head_diameter=2.0 * d,
                color=color))
        upd = fm.SceneUpdate(entities=[fm.SceneEntity(timestamp=stamp, frame_id="world", id="contact_forces",
                                                      arrows=arrows)])
        self._w.add_message(self._ch["forces"], lt, upd.encode(), lt, seq)

    def tick(self) -> None:
        """Close the open chunk if it is older than the wall-time interval."""
        if self._open and time.monotonic() - self._last_flush_wall >= self.flush_wall_interval:
            self.flush()

    def finish(self, outcome: dict) -> None:
        """Close the last chunk, write the outcome, the metadata's second copy and the
        summary; close a file this sink opened (after ``fsync``)."""
        if self.finished:
            return
        self.flush()
        self._w.add_metadata("qchain.outcome", seal(outcome_entries(outcome, self.n_records, self.last_t)))
        self._w.add_metadata("qchain", self._meta)
        self._w.finish()
        self._stream.flush()
        if self._owns:
            os.fsync(self._stream.fileno())
            self._stream.close()
        self.finished = True

    def abandon(self) -> None:
        """Close a file this sink opened without finishing it (its chunks stay readable)."""
        if self._owns and not self._stream.closed:
            with suppress(OSError):
                self._stream.close()


def outcome_entries(outcome: dict, n_records: int, last_t: float | None) -> dict[str, str]:
    """The ``qchain.outcome`` metadata entries."""
    return {
        "success": "true" if outcome.get("success") else "false",
        "status": str(int(outcome.get("status", 0))),
        "message": str(outcome.get("message", "")),
        "nfev": str(int(outcome.get("nfev", 0) or 0)),
        "n_records": str(n_records),
        "last_t": "" if last_t is None else repr(float(last_t)),
    }
