"""The Rerun view of a run: live (a served web viewer, a viewer you run) or an ``.rrd`` file.

What it shows is in docs/recording.md, "The viewers". Per-step data go on the ``sim_time``
(duration) and ``step`` (sequence) timelines in column batches (``send_columns``); the served
web viewer sits behind :mod:`.web_viewer`, with Rerun's analytics turned off."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import suppress
from pathlib import Path
from urllib.parse import quote, urlsplit

import numpy as np

from .records import SEGMENT_COLORS, Batch, LoggingError, RunInfo
from .scenery import CONTACT_COLOR, OBSTACLE_COLOR, TENDON_COLOR, force_scale, motion_offset, obstacle_shapes, tendon_strips
from .scenery import reach as arm_reach

__all__ = ["RerunSink", "camera", "probe_viewer", "bound_rerun_exit", "CONNECT_TIMEOUT", "DEFAULT_BIND",
           "DEFAULT_GRPC_PORT", "DEFAULT_WEB_PORT", "quiet_env"]

DEFAULT_BIND = "127.0.0.1"
DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
#: Vertical field of view (deg) of Rerun's 3D view camera.
FOV_Y_DEG = 55.0


def quiet_env(env: dict | None = None) -> dict:
    """An environment in which Rerun (SDK and viewer) sends no analytics anywhere."""
    env = dict(os.environ if env is None else env)
    env["RERUN_ANALYTICS"] = "0"  # read by rerun-sdk's Python side
    env["DO_NOT_TRACK"] = "1"
    env.setdefault("RUST_LOG", "warn")
    # the analytics setting of the rerun program lives in its config folder: one of our own,
    # with analytics off (`rerun analytics disable` would change the user's)
    cfg = Path(env.get("XDG_CONFIG_HOME") or Path.home() / ".config")
    if not (cfg / "rerun" / "analytics.json").exists():
        import tempfile

        own = Path(tempfile.gettempdir()) / f"qchain-rerun-config-{os.getuid()}"
        with suppress(OSError):  # no config folder of our own: the variables above still hold
            (own / "rerun").mkdir(parents=True, exist_ok=True)
            f = own / "rerun" / "analytics.json"
            if not f.exists():
                f.write_text(json.dumps({"analytics_enabled": False, "opt_in_metadata": {}}))
            env["XDG_CONFIG_HOME"] = str(own)
    return env


def _pressure_colors(p_rel: np.ndarray) -> np.ndarray:
    """Colours (..., 3) uint8 for pressures relative to the reference, blue (0) to red (1)."""
    s = np.clip(np.nan_to_num(p_rel), 0.0, 1.0)[..., None]
    lo = np.array([60.0, 120.0, 255.0])
    hi = np.array([220.0, 20.0, 60.0])
    return (lo + (hi - lo) * s).astype(np.uint8)


def _quat_rot(qxyzw: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) x, y, z, w."""
    x, y, z, w = np.moveaxis(np.asarray(qxyzw, dtype=float), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def camera(base: np.ndarray, reach: float, fov_deg: float = FOV_Y_DEG, margin: float = 1.05):
    """Eye position, look target and up vector that frame the arm's whole reach.

    The arm stays within a ball of radius ``reach`` (its length) about its base, on the
    base's side of it. The camera looks at the point half a reach along the base's z axis,
    from a distance at which a sphere of radius 1.25 reach about that point (which holds
    that ball's part in front of the base) fits the view's height (times ``margin``), from
    a side: perpendicular to the base axis where it can, world z up.

    Parameters
    ----------
    base : (7,) x, y, z (m), qx, qy, qz, qw: the base's world placement.
    reach : float, m
    """
    o = np.asarray(base[:3], dtype=float)
    z_b = _quat_rot(np.asarray(base[3:7], dtype=float))[:, 2]
    target = o + 0.5 * reach * z_b
    up = np.array([0.0, 0.0, 1.0])
    side = np.array([0.55, -0.8, 0.0])  # a three-quarter view
    side -= np.dot(side, z_b) * z_b  # perpendicular to the arm's axis
    if np.linalg.norm(side) < 1e-6:
        side = np.array([0.0, -1.0, 0.0])
    side /= np.linalg.norm(side)
    view = side + 0.35 * up  # a little from above
    view /= np.linalg.norm(view)
    # what the arm reaches (a ball of radius reach about the base, on the base's side of it)
    # lies within 1.25 reach of the target; at this distance that sphere fits the view
    radius = 1.25 * reach
    dist = margin * radius / np.sin(np.radians(0.5 * fov_deg))
    return target + dist * view, target, up


def listen_address(bind: str) -> str:
    """The IPv4 address a server listens on for ``bind`` (an IPv4 address, or a host name
    resolved to its first IPv4 address: Rerun's server takes addresses only). IPv6 is not
    served (the viewer's page is served and linked on IPv4).

    Raises
    ------
    LoggingError
        naming ``bind``: an IPv6 address, or a name with no IPv4 address.
    """
    import ipaddress

    text = str(bind)
    try:
        ip = ipaddress.ip_address(text.strip("[]"))
    except ValueError:
        ip = None
    if ip is not None:
        if ip.version != 4:
            raise LoggingError(f"bind: expected an IPv4 address (IPv6 is not served), found {text[:80]!r}: use "
                               "127.0.0.1 (this machine) or 0.0.0.0 (every interface)")
        return str(ip)
    try:
        infos = socket.getaddrinfo(text, None, socket.AF_INET, socket.SOCK_STREAM)
    except (OSError, UnicodeError) as exc:
        raise LoggingError(f"bind: the host name {text[:80]!r} has no IPv4 address ({exc})") from None
    return str(infos[0][4][0])


def _pick_port(host: str, preferred: int | None, default: int) -> int:
    """``preferred`` if given; else ``default`` when free on ``host``, else a free port."""
    if preferred:
        return int(preferred)
    for candidate in (default, 0):
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
                s.bind((host, candidate))
                return int(s.getsockname()[1])
        except OSError:
            continue
    raise LoggingError(f"no free TCP port on {host}")


def _wait_listening(host: str, port: int, timeout: float, proc: subprocess.Popen | None = None) -> bool:
    deadline = time.monotonic() + timeout
    target = "127.0.0.1" if host in ("0.0.0.0", "") else host
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            return False
        try:
            with socket.create_connection((target, port), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.05)
    return False


#: s a Rerun viewer at ``connect`` has to answer a connection, and to take a run's data.
CONNECT_TIMEOUT = 10.0
_H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"  # + empty SETTINGS


def probe_viewer(url: str, timeout: float = CONNECT_TIMEOUT) -> str | None:
    """None when a Rerun viewer (a gRPC server) answers at ``url`` within ``timeout`` s,
    else why not, in words: an unsupported URL, a closed port, a host that cannot be
    reached, a peer that accepts the connection and never answers (its HTTP/2 settings for
    ``rerun+http``, the TLS handshake for ``rerun+https`` and ``rerun``), or one that
    answers as something else.

    A TCP connection alone proves nothing: the Rerun SDK waits for a peer that accepts and
    never answers without end (when it flushes, disconnects, and at interpreter exit)."""
    parts = urlsplit(url)
    if parts.scheme not in ("rerun", "rerun+http", "rerun+https", "http", "https"):
        return f"unsupported URL scheme {parts.scheme!r} (use rerun+http://HOST:PORT/proxy)"
    host = parts.hostname
    if not host:
        return "the URL names no host"
    try:
        port = parts.port or (9876 if parts.scheme.startswith("rerun") else 443 if parts.scheme == "https" else 80)
    except ValueError as exc:
        return f"bad port in the URL ({exc})"
    tls = parts.scheme in ("rerun", "rerun+https", "https")
    deadline = time.monotonic() + timeout
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except socket.timeout:
        return f"no connection within {timeout:g} s"
    except OSError as exc:
        return exc.strerror or str(exc)
    try:
        sock.settimeout(max(0.05, deadline - time.monotonic()))
        if tls:
            import ssl

            ctx = ssl.create_default_context()
            ctx.set_alpn_protocols(["h2"])
            # it answered (a certificate problem is the SDK's to report, within the deadline)
            with suppress(ssl.SSLError):
                ctx.wrap_socket(sock, server_hostname=host).close()
            return None
        sock.sendall(_H2_PREFACE)
        got = b""
        while len(got) < 9:
            sock.settimeout(max(0.05, deadline - time.monotonic()))
            piece = sock.recv(9 - len(got))
            if not piece:
                return "the peer closed the connection without answering (not a Rerun viewer?)"
            got += piece
        if got[3] != 0x04:  # the first frame an HTTP/2 server sends is its SETTINGS
            return "the peer answered, but not as an HTTP/2 (gRPC) server: not a Rerun viewer?"
        return None
    except socket.timeout:
        return f"the peer accepted the connection but did not answer within {timeout:g} s"
    except OSError as exc:
        return exc.strerror or str(exc)
    finally:
        sock.close()


_EXIT_BOUNDED = False
_ABANDONED: list = []  # recording streams whose peer stopped answering (RerunSink.abandon)


def bound_rerun_exit(limit: float = 5.0) -> None:
    """Let this process's exit wait at most ``limit`` s for Rerun's own shutdown.

    The Rerun SDK flushes every recording at interpreter exit (an ``atexit`` handler), and
    waits without end for a peer that stopped taking data. Once such a peer was given up,
    that handler is replaced by one that runs it on a thread and waits at most ``limit`` s
    (what the other recordings of the process have still gets its chance)."""
    global _EXIT_BOUNDED
    if _EXIT_BOUNDED:
        return
    import atexit

    import rerun as rr

    rr.unregister_shutdown()

    def bounded() -> None:
        th = threading.Thread(target=rr.rerun_shutdown, name="qchain-rerun-shutdown", daemon=True)
        th.start()
        th.join(limit)

    atexit.register(bounded)
    _EXIT_BOUNDED = True


def rerun_cli() -> str | None:
    """Path of the ``rerun`` program shipped in the rerun-sdk wheel (or on PATH)."""
    with suppress(ImportError):
        import rerun_cli as _rc

        exe = Path(_rc.__file__).parent / ("rerun.exe" if os.name == "nt" else "rerun")
        if exe.exists():
            return str(exe)
    import shutil

    return shutil.which("rerun")


def _die_with_parent(sig: int = signal.SIGTERM) -> None:  # in a child: the web viewer's before exec, replay's sender
    if sys.platform.startswith("linux"):
        with suppress(OSError, AttributeError):
            import ctypes

            ctypes.CDLL(None).prctl(1, sig)  # PR_SET_PDEATHSIG


def _reap(proc: subprocess.Popen, kill_after: float | None = 30.0) -> None:
    """Wait for a child's exit (it ends on its own, within its deadlines); kill it after
    ``kill_after`` s (None: one left to finish a recording is not cut short)."""
    try:
        proc.wait(kill_after)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _bounded(fn, limit: float, name: str) -> None:
    """Run ``fn()`` on a daemon thread and wait for it at most ``limit`` s (its exceptions
    are dropped: this is for taking leave)."""
    def run():
        with suppress(Exception):
            fn()

    th = threading.Thread(target=run, name=name, daemon=True)
    th.start()
    th.join(limit)


class RerunSink:
    """Logs batches to a Rerun recording stream (live server, remote viewer, .rrd file)."""

    def __init__(self, info: RunInfo, *, serve: bool = False, connect: str | None = None,
                 rrd: str | os.PathLike | None = None, bind: str = DEFAULT_BIND, grpc_port: int | None = None,
                 web_port: int | None = None, recording_id: str, server_memory_limit: str = "1GiB", warn,
                 viewer_timeout: float = CONNECT_TIMEOUT):
        self.info = info
        self.rec = None
        self.viewer_url: str | None = None
        self.grpc_url: str | None = None
        self.serving = False
        self.web: subprocess.Popen | None = None
        self.front = None
        self.started = False
        self._moving: list = []  # (entity path, motion) of the moving obstacles (_log_obstacles)
        os.environ.update({k: v for k, v in quiet_env().items() if k in ("RERUN_ANALYTICS", "DO_NOT_TRACK")})
        import rerun as rr
        import rerun.blueprint as rrb

        self.rr, self.rrb = rr, rrb
        rec = rr.RecordingStream("qchain", recording_id=recording_id)
        sinks = []
        if rrd is not None:
            sinks.append(rr.FileSink(os.fspath(rrd)))
        if connect:  # a viewer that does not answer would hold this process without end
            why = probe_viewer(connect, viewer_timeout)
            if why is None:
                sinks.append(rr.GrpcSink(connect))
            else:
                warn(f"no Rerun viewer can be reached at {connect} ({why}); the run goes on without it and the "
                     "MCAP log is still written")
        server_port = None
        if serve:
            bind = listen_address(bind)
            server_port = _pick_port(bind, grpc_port, DEFAULT_GRPC_PORT)
            server = rr.GrpcServerSink(bind_ip=bind, port=server_port, server_memory_limit=server_memory_limit)
            sinks.append(server)
            self.grpc_url = server.uri
        if not sinks:
            return
        rec.set_sinks(*sinks)
        self.rec = rec
        if serve:
            if not _wait_listening(bind, server_port, 5.0):
                warn(f"the Rerun gRPC server could not listen on {bind}:{server_port} (port in use?); no live "
                     "view, the MCAP log is still written")
            else:
                self.serving = True
                self._start_web_viewer(bind, web_port, warn)
        rec.send_recording_name(info.name)

    def _start_web_viewer(self, bind: str, web_port: int | None, warn) -> None:
        exe = rerun_cli()
        if exe is None:
            warn("the `rerun` program of rerun-sdk was not found, so no web viewer is served; open the data with "
                 f"a Rerun viewer: rerun --connect {self.grpc_url}")
            return
        from .web_viewer import LoopbackFront

        port = _pick_port(bind, web_port, DEFAULT_WEB_PORT)
        inner = _pick_port("127.0.0.1", None, 0)  # the rerun program's own server, behind the front
        self.web = subprocess.Popen(
            [exe, "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(inner), self.grpc_url],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=quiet_env(),
            preexec_fn=_die_with_parent,
        )
        if not _wait_listening("127.0.0.1", inner, 15.0, self.web):
            warn(f"the Rerun web viewer did not start; connect a Rerun viewer to {self.grpc_url} instead")
            self._stop_web()
            return
        try:
            self.front = LoopbackFront(bind, port, inner, int(urlsplit(self.grpc_url).port))
        except OSError as exc:
            warn(f"the web viewer cannot be served on {bind}:{port} ({exc.strerror or exc}); connect a Rerun viewer "
                 f"to {self.grpc_url} instead")
            self._stop_web()
            return
        host = "127.0.0.1" if bind in ("0.0.0.0", "") else bind
        self.viewer_url = f"http://{host}:{port}/?url={quote(self.grpc_url, safe='')}"

    def _stop_web(self) -> None:
        front, self.front = getattr(self, "front", None), None
        if front is not None:
            front.close()
        if self.web is not None and self.web.poll() is None:
            self.web.terminate()
            _reap(self.web, 5.0)
        self.web = None

    # -- static part ---------------------------------------------------------------------

    def blueprint(self, b: Batch):
        """The view: 3D arm beside the plots (built from a run's first records)."""
        rrb, info = self.rrb, self.info
        reach = self._reach(b)
        eye, target, up = camera(b.base[0], reach)
        hidden = rrb.PlotLegend(visible=False)  # names show on hover: no legend over the data
        t_end = info.duration
        axis = None
        if t_end is not None:
            B = self.rr.TimeRangeBoundary
            axis = rrb.TimeAxis(view_range=self.rr.TimeRange(start=B.absolute(seconds=0.0),
                                                             end=B.absolute(seconds=float(t_end))))

        def plot(name, origin):
            return rrb.TimeSeriesView(name=name, origin=origin, plot_legend=hidden, axis_x=axis)

        n = self.info.n_segments
        q_views = [plot(f"segment {i + 1} coordinates", f"/plots/q/segment_{i + 1}") for i in range(n)]
        if self._seg_q0(b) > 0:  # a floating base's coordinates
            q_views.insert(0, plot("base coordinates", "/plots/q/base"))
        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Spatial3DView(name="arm", origin="/", contents=["+ /arm/**", "+ /world/**"],
                                  eye_controls=rrb.EyeControls3D(position=eye, look_target=target, eye_up=up)),
                rrb.Vertical(
                    plot("chamber pressures [Pa]", "/plots/pressure"),
                    *([plot("tendon tensions [N]", "/plots/tension")] if b.tension is not None else []),
                    rrb.Tabs(*q_views, plot("velocities", "/plots/v"), rrb.TextDocumentView(name="scene",
                                                                                            origin="/scene")),
                    plot("energy [J]", "/plots/energy"),
                ),
                column_shares=[3, 2],
            ),
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="collapsed", timeline="sim_time"),
        )

    def _seg_q0(self, b: Batch) -> int:
        """Index of the first segment coordinate (after the base's)."""
        return max(0, b.q.shape[1] - 3 * self.info.n_segments)

    @staticmethod
    def _drawn_lengths(b: Batch) -> np.ndarray:
        """Lengths (n,) m of the segments as the first record's backbone draws them."""
        n, P = b.backbone.shape[1], b.backbone.shape[2]
        return np.linalg.norm(np.diff(np.nan_to_num(b.backbone[0]), axis=1), axis=2).sum(axis=1) if P > 1 \
            else np.zeros(n)

    def _reach(self, b: Batch) -> float:
        return arm_reach(self.info, b.backbone[0])

    def _start(self, b: Batch) -> None:
        rr, rec, info = self.rr, self.rec, self.info
        n = b.backbone.shape[1]
        seg_len = self._drawn_lengths(b)
        seg_len = np.where(seg_len > 0, seg_len, 4.0 * np.asarray(info.radii))
        self._arrow_scale = 0.5 * seg_len / info.pressure_ref  # m/Pa, (n,)
        radii = np.asarray(info.radii)
        self._axis_len = 2.5 * radii
        self._chamber_r = np.asarray(info.chamber_radii) if info.chamber_radii is not None else 0.6 * radii
        ang = np.asarray(info.chamber_angles)
        self._cos, self._sin = np.cos(ang), np.sin(ang)
        colors = np.array([SEGMENT_COLORS[i % len(SEGMENT_COLORS)] for i in range(n)], dtype=np.uint8)
        reach_ = self._reach(b)
        rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("world/axes", rr.Arrows3D(origins=np.zeros((3, 3)), vectors=np.eye(3) * 0.25 * reach_,
                                          colors=[(200, 60, 60), (60, 170, 60), (60, 90, 220)],
                                          radii=0.05 * float(radii.min())), static=True)
        rec.log("arm/backbone", rr.LineStrips3D.from_fields(radii=radii, colors=colors), static=True)
        rec.log("arm/tip_axes", rr.Arrows3D.from_fields(
            colors=np.tile(np.array([(220, 40, 40), (40, 180, 40), (40, 80, 230)], np.uint8), (n, 1)),
            radii=np.repeat(0.12 * radii, 3)), static=True)
        rec.log("arm/pressure", rr.Arrows3D.from_fields(radii=np.repeat(0.08 * radii, 3)), static=True)
        rec.log("plots/pressure", rr.SeriesLines(names=info.names("p", b.p.shape[1])), static=True)
        if b.tension is not None:
            rec.log("plots/tension", rr.SeriesLines(names=[f"tendon {i} [N]" for i in range(b.tension.shape[1])]),
                    static=True)
        if b.tendons is not None:
            rec.log("arm/tendons", rr.LineStrips3D.from_fields(radii=0.15 * float(radii.min()), colors=[TENDON_COLOR]),
                    static=True)
        qn = info.names("q", b.q.shape[1])
        s0 = self._seg_q0(b)
        self._q_groups = [("base", slice(0, s0))] if s0 else []
        self._q_groups += [(f"segment_{i + 1}", slice(s0 + 3 * i, s0 + 3 * i + 3)) for i in range(n)]
        for key, sl in self._q_groups:
            rec.log(f"plots/q/{key}", rr.SeriesLines(names=qn[sl]), static=True)
        rec.log("plots/v", rr.SeriesLines(names=info.names("v", b.v.shape[1])), static=True)
        rec.log("plots/energy", rr.SeriesLines(names=info.names("energy", 3),
                                               colors=[(40, 120, 220), (60, 170, 60), (30, 30, 30)]), static=True)
        text = f"# {info.name}\n\nqchain {info.qchain_version}, {n} segment(s)"
        if info.scene_path:
            text += f", scene `{info.scene_path}`"
        if info.scene:
            text += "\n\n```toml\n" + info.scene + "\n```"
        if info.params:
            text += "\n\n## Model parameters\n\n```json\n" + json.dumps(info.params, indent=2, sort_keys=True) + "\n```"
        rec.log("scene", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
        self._contact_scale = force_scale(reach_, info.force_ref)
        self._log_obstacles(2.0 * reach_)
        if b.contacts is not None:
            rec.log("world/contacts/forces", rr.Arrows3D.from_fields(radii=0.3 * float(radii.min()),
                                                                     colors=[CONTACT_COLOR]), static=True)
            rec.log("world/contacts/points", rr.Points3D.from_fields(radii=0.5 * float(radii.min()),
                                                                     colors=[CONTACT_COLOR]), static=True)
        rec.send_blueprint(self.blueprint(b), make_active=True, make_default=True)
        self.started = True

    def _log_obstacles(self, extent: float) -> None:
        """The obstacles as static shapes under ``world/obstacles/<i>`` (a half-space: a thin
        slab ``2 extent`` m wide), drawn where they are at ``t = 0``; a moving one's entity gets
        its translation each sample (:meth:`_send_obstacle_motion`)."""
        rr, rec = self.rr, self.rec
        color = [OBSTACLE_COLOR + (160,)]
        for sh in obstacle_shapes(self.info.obstacles, extent):
            i = sh.index
            path = f"world/obstacles/{i}"
            if self.info.obstacles[i].get("motion") is not None:
                self._moving.append((path, self.info.obstacles[i]["motion"]))
            if sh.kind == "box":
                rec.log(path, rr.Boxes3D(centers=[sh.center], half_sizes=[0.5 * sh.size], quaternions=[sh.quaternion],
                                         colors=color, fill_mode="solid"), static=True)
            elif sh.kind == "sphere":
                rec.log(path, rr.Ellipsoids3D(centers=[sh.center], half_sizes=[0.5 * sh.size], colors=color,
                                              fill_mode="solid"), static=True)
            elif sh.kind == "cylinder":
                rec.log(path, rr.Cylinders3D(centers=[sh.center], lengths=[sh.size[2]], radii=[0.5 * sh.size[0]],
                                             quaternions=[sh.quaternion], colors=color, fill_mode="solid"), static=True)
            else:  # a capsule: Rerun's runs along its own z from its translation (the axis's start)
                a = np.asarray(self.info.obstacles[i]["a"], dtype=float)
                rec.log(path, rr.Capsules3D(translations=[a], lengths=[sh.size[2]], radii=[0.5 * sh.size[0]],
                                            quaternions=[sh.quaternion], colors=color, fill_mode="solid"), static=True)

    def _send_obstacle_motion(self, b: Batch, idx) -> None:
        """Each moving obstacle's translation from ``t = 0`` at every record, as the
        ``Transform3D`` of its entity (its static shape is drawn in that entity's frame), from
        the law in ``RunInfo.obstacles``: a replay recomputes it from the records' times."""
        for path, motion in self._moving:
            self.rec.send_columns(path, indexes=idx,
                                  columns=self.rr.Transform3D.columns(translation=motion_offset(motion, b.t)))

    def _send_contacts(self, b: Batch, idx) -> None:
        """Each record's contact forces as arrows at the contact points (and the points)."""
        rr, rec = self.rr, self.rec
        K = len(b)
        sets = [b.contact_set(k) for k in range(K)]
        counts = np.array([len(c.segment) for c in sets])
        points = np.concatenate([c.point for c in sets]) if K else np.zeros((0, 3))
        forces = np.concatenate([c.force for c in sets]) if K else np.zeros((0, 3))
        rec.send_columns("world/contacts/forces", indexes=idx, columns=rr.Arrows3D.columns(
            origins=points, vectors=forces * self._contact_scale).partition(counts))
        rec.send_columns("world/contacts/points", indexes=idx,
                         columns=rr.Points3D.columns(positions=points).partition(counts))

    # -- per-step part -----------------------------------------------------------------------

    def write_batch(self, b: Batch) -> None:
        if self.rec is None or len(b) == 0:
            return
        rr, rec = self.rr, self.rec
        if not self.started:
            self._start(b)
        K, n, P = b.backbone.shape[:3]
        idx = [rr.TimeColumn("sim_time", duration=b.t), rr.TimeColumn("step", sequence=b.step)]
        rec.send_columns("arm/backbone", indexes=idx, columns=rr.LineStrips3D.columns(
            strips=b.backbone.reshape(K * n, P, 3)).partition(np.full(K, n)))
        pos = b.tip_frames[..., :3]  # (K, n, 3)
        R = _quat_rot(b.tip_frames[..., 3:])  # (K, n, 3, 3)
        axes = np.swapaxes(R, -1, -2) * self._axis_len[None, :, None, None]  # rows = axis vectors
        rec.send_columns("arm/tip_axes", indexes=idx, columns=rr.Arrows3D.columns(
            origins=np.repeat(pos, 3, axis=1).reshape(-1, 3), vectors=axes.reshape(-1, 3)).partition(np.full(K, 3 * n)))
        # chamber arrows: at the chamber centres on each tip plate, along the backbone's end
        # tangent, length and colour by pressure
        radial = self._cos[None, None, :, None] * R[:, :, None, :, 0] + self._sin[None, None, :, None] * R[:, :, None, :, 1]
        origins = pos[:, :, None, :] + self._chamber_r[None, :, None, None] * radial
        tangent = b.backbone[:, :, -1, :] - b.backbone[:, :, -2, :] if P > 1 else R[..., 2]
        tangent = tangent / np.maximum(np.linalg.norm(tangent, axis=-1, keepdims=True), 1e-300)
        npress = min(b.p.shape[1], 3 * n)
        press = np.zeros((K, 3 * n))
        press[:, :npress] = b.p[:, :npress]
        press = press.reshape(K, n, 3)
        vec = tangent[:, :, None, :] * (press * self._arrow_scale[None, :, None])[..., None]
        rec.send_columns("arm/pressure", indexes=idx, columns=rr.Arrows3D.columns(
            origins=origins.reshape(-1, 3), vectors=vec.reshape(-1, 3),
            colors=_pressure_colors(press / self.info.pressure_ref).reshape(-1, 3)).partition(np.full(K, 3 * n)))
        rec.send_columns("plots/pressure", indexes=idx, columns=rr.Scalars.columns(scalars=b.p))
        if b.tension is not None:
            rec.send_columns("plots/tension", indexes=idx, columns=rr.Scalars.columns(scalars=b.tension))
        if b.tendons is not None:  # each tendon a strip of its finite points (a path to mid-arm is shorter)
            points, lengths = tendon_strips(b.tendons)
            strips = np.split(points, np.cumsum(lengths)[:-1])
            rec.send_columns("arm/tendons", indexes=idx, columns=rr.LineStrips3D.columns(strips=strips).partition(
                np.full(K, b.tendons.shape[1])))
        for key, sl in self._q_groups:
            rec.send_columns(f"plots/q/{key}", indexes=idx, columns=rr.Scalars.columns(scalars=b.q[:, sl]))
        rec.send_columns("plots/v", indexes=idx, columns=rr.Scalars.columns(scalars=b.v))
        rec.send_columns("plots/energy", indexes=idx, columns=rr.Scalars.columns(scalars=b.energy))
        if self._moving:
            self._send_obstacle_motion(b, idx)
        if b.contacts is not None:
            self._send_contacts(b, idx)

    def finish(self) -> None:
        """Flush everything; finalise a .rrd file (keep a live server up)."""
        if self.rec is None:
            return
        self.rec.flush(timeout_sec=10.0)
        if not self.serving:
            self.rec.disconnect()
        else:
            with suppress(Exception):  # pragma: no cover - best effort
                import rerun_bindings

                rerun_bindings.finalize_deferred_sinks(recording=self.rec.to_native())

    def close(self) -> None:
        if self.rec is not None:
            self.rec.disconnect()
            self.rec = None
        self._stop_web()
        self.serving = False

    def abandon(self) -> None:
        """Never wait for this stream's peer again (it stopped answering): the stream is
        kept for the life of the process (collecting it, Rerun flushes it, and so waits for
        the peer without end, at the latest at interpreter exit) and Rerun's own exit
        handler is bounded (:func:`bound_rerun_exit`)."""
        rec = self.rec
        if rec is not None and rec not in _ABANDONED:
            _ABANDONED.append(rec)
            # also through the interpreter's teardown, which clears module globals
            with suppress(ImportError, AttributeError, OSError):  # (not CPython: nothing to keep it with)
                import ctypes

                ctypes.pythonapi.Py_IncRef(ctypes.py_object(rec))
        bound_rerun_exit()
