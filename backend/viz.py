"""The live 3D arm (viser): what makes the numbers believable.

One :class:`viser.ViserServer` per service, on its own port (viser ships its own client: no
CDN). It shows one device at a time, the one a dashboard selected
(``PUT /api/viz/device``): the shoulder, elbow and wrist with both segments, the IMU on the
upper arm, the nominal shoulder with its tolerance circle, a fading trace of the shoulder
coloured by state, and the robot's two cuffs with their ropes (schematic anchors).

Every scene handle is created once, when the server starts; a frame only changes
properties (positions, orientations, scales, colours, line points). The server starts
lazily, the first time a dashboard asks for the 3D view, so a service nobody watches in
3D pays nothing but keeping the last row per device.

The live side feeds it with :meth:`Viz.update` (the same ``rows`` as the WebSocket
``estimate`` message); it is cheap, thread-safe and never raises into the caller.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

TRACE_POINTS = 240  # shoulder trace: ~8 s at 30 updates/s
CIRCLE_SEGMENTS = 72
MAX_FPS = 30.0
CAMERA_OFFSET = np.array([0.5, -0.4, 0.32])  # from the arm's middle: front-side, above

# Okabe–Ito, as on the dashboard: ok, outside, warning; gray when unknown.
STATE_RGB: dict[str | None, tuple[int, int, int]] = {
    "ok": (0, 158, 115),
    "outside": (0, 114, 178),
    "warning": (230, 159, 0),
    None: (140, 140, 140),
}
BACKGROUND = np.array([255.0, 255.0, 255.0])
BONE = (205, 210, 218)
JOINT = (90, 98, 110)
CUFF = (60, 60, 70)
ROPE = (120, 80, 40)
IMU = (204, 121, 167)


@dataclass
class DeviceFrame:
    """The newest pose of one device and its recent shoulder trace."""

    shoulder: F64 | None = None
    elbow: F64 | None = None
    wrist: F64 | None = None
    nominal: F64 | None = None
    state: str | None = None
    trace: deque[tuple[float, float, float, str | None]] = field(
        default_factory=lambda: deque(maxlen=TRACE_POINTS)
    )
    tolerance_m: float = 0.10
    cuff_to_elbow_m: float = 0.06
    imu_to_elbow_m: float = 0.15
    anchors: F64 | None = None  # rope anchors, fixed once the first wrist is seen
    version: int = 0


def _col(rows: Mapping[str, Sequence[Any]], name: str, i: int) -> float | None:
    col = rows.get(name)
    if col is None or i >= len(col):
        return None
    v = col[i]
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _point(rows: Mapping[str, Sequence[Any]], prefix: str, i: int) -> F64 | None:
    xyz = [_col(rows, f"{prefix}_{a}", i) for a in "xyz"]
    if any(v is None for v in xyz):
        return None
    return np.array(xyz, dtype=np.float64)


def quat_z_to(direction: F64) -> F64:
    """Unit quaternion (wxyz) rotating +z onto ``direction``."""
    n = float(np.linalg.norm(direction))
    if n < 1e-9:
        return np.array([1.0, 0.0, 0.0, 0.0])
    d = direction / n
    z = np.array([0.0, 0.0, 1.0])
    c = float(np.dot(z, d))
    if c < -0.999999:
        return np.array([0.0, 1.0, 0.0, 0.0])
    axis = np.cross(z, d)
    q = np.array([1.0 + c, axis[0], axis[1], axis[2]])
    out: F64 = q / np.linalg.norm(q)
    return out


def quat_x_to(direction: F64) -> F64:
    """Unit quaternion (wxyz) rotating +x onto ``direction``, keeping y horizontal."""
    n = float(np.linalg.norm(direction))
    if n < 1e-9:
        return np.array([1.0, 0.0, 0.0, 0.0])
    x = direction / n
    y = np.cross(np.array([0.0, 0.0, 1.0]), x)
    if np.linalg.norm(y) < 1e-6:
        y = np.array([0.0, 1.0, 0.0])
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    m = np.stack([x, y, z], axis=1)
    w = math.sqrt(max(0.0, 1.0 + m[0, 0] + m[1, 1] + m[2, 2])) / 2.0
    if w > 1e-6:
        return np.array(
            [
                w,
                (m[2, 1] - m[1, 2]) / (4 * w),
                (m[0, 2] - m[2, 0]) / (4 * w),
                (m[1, 0] - m[0, 1]) / (4 * w),
            ]
        )
    # 180° turn: pick the largest diagonal element.
    i = int(np.argmax(np.diag(m)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(max(1e-12, 1.0 + m[i, i] - m[j, j] - m[k, k])) * 2.0
    q = np.zeros(4)
    q[0] = (m[k, j] - m[j, k]) / s
    q[1 + i] = 0.25 * s
    q[1 + j] = (m[j, i] + m[i, j]) / s
    q[1 + k] = (m[k, i] + m[i, k]) / s
    out: F64 = q / np.linalg.norm(q)
    return out


def unit_circle(n: int = CIRCLE_SEGMENTS) -> F64:
    """Segments (n, 2, 3) of a unit circle in the horizontal plane."""
    a = np.linspace(0.0, 2 * np.pi, n + 1)
    pts = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    return np.stack([pts[:-1], pts[1:]], axis=1)


def trace_segments(
    trace: Sequence[tuple[float, float, float, str | None]],
) -> tuple[F64, NDArray[np.uint8]]:
    """Line segments (TRACE_POINTS-1, 2, 3) and colours of the shoulder trace, older points
    fading into the background; unused segments collapse onto the newest point."""
    n = TRACE_POINTS - 1
    pts = np.zeros((n, 2, 3))
    cols = np.tile(BACKGROUND.astype(np.uint8), (n, 2, 1))
    m = len(trace)
    if m == 0:
        return pts, cols
    xyz = np.array([p[:3] for p in trace], dtype=np.float64)
    rgb = np.array([STATE_RGB.get(p[3], STATE_RGB[None]) for p in trace], dtype=np.float64)
    age = np.linspace(1.0, 0.0, m) if m > 1 else np.zeros(1)  # 1 = oldest
    fade = (1.0 - 0.75 * age)[:, None]  # the oldest still visible against the white
    rgb = rgb * fade + BACKGROUND * (1.0 - fade)
    pts[:] = xyz[-1]
    if m > 1:
        k = m - 1
        pts[n - k :, 0] = xyz[:-1]
        pts[n - k :, 1] = xyz[1:]
        cols[n - k :, 0] = rgb[:-1].round().astype(np.uint8)
        cols[n - k :, 1] = rgb[1:].round().astype(np.uint8)
    return pts, cols


class _Scene:
    """The handles of the arm scene, created once on a running server."""

    def __init__(self, server: Any) -> None:
        import viser  # noqa: F401  (typing only through Any: viser is an optional runtime)

        s = server.scene
        s.set_up_direction("+z")
        self.root = s.add_frame("/arm", show_axes=False)
        self.floor = s.add_grid(
            "/arm/table",
            width=1.2,
            height=1.2,
            cell_size=0.05,
            section_size=0.25,
            plane="xy",
            position=(0.0, 0.0, 0.0),
            visible=False,
        )
        self.shoulder = s.add_icosphere("/arm/shoulder", radius=0.03, color=STATE_RGB[None])
        self.elbow = s.add_icosphere("/arm/elbow", radius=0.024, color=JOINT)
        self.wrist = s.add_icosphere("/arm/wrist", radius=0.02, color=JOINT)
        self.upper = s.add_cylinder("/arm/upper_arm", radius=0.022, height=1.0, color=BONE)
        self.fore = s.add_cylinder("/arm/forearm", radius=0.019, height=1.0, color=BONE)
        self.imu = s.add_box("/arm/imu", dimensions=(0.05, 0.035, 0.018), color=IMU)
        self.nominal = s.add_icosphere(
            "/arm/nominal", radius=0.012, color=(110, 110, 110), opacity=0.8, visible=False
        )
        self.tolerance = s.add_line_segments(
            "/arm/nominal_ring",
            points=unit_circle(),
            colors=(120, 120, 120),
            thickness=0.006,
            scale=0.10,
            visible=False,
        )
        pts, cols = trace_segments([])
        self.trace = s.add_line_segments(
            "/arm/shoulder_trace", points=pts, colors=cols, thickness=0.012
        )
        self.wrist_cuff = s.add_cylinder(
            "/arm/wrist_cuff", radius=0.038, height=0.03, color=CUFF, opacity=0.85
        )
        self.prox_cuff = s.add_cylinder(
            "/arm/proximal_cuff", radius=0.042, height=0.03, color=CUFF, opacity=0.85
        )
        self.ropes = s.add_line_segments(
            "/arm/ropes", points=np.zeros((4, 2, 3)), colors=ROPE, thickness=0.004
        )
        self.handles = [
            self.shoulder,
            self.elbow,
            self.wrist,
            self.upper,
            self.fore,
            self.imu,
            self.wrist_cuff,
            self.prox_cuff,
            self.ropes,
            self.trace,
        ]
        self.camera_set = False

    def hide(self) -> None:
        for h in (*self.handles, self.nominal, self.tolerance, self.floor):
            h.visible = False
        self.camera_set = False

    @staticmethod
    def _segment(handle: Any, a: F64, b: F64) -> None:
        d = b - a
        handle.position = tuple((a + b) / 2.0)
        handle.wxyz = tuple(quat_z_to(d))
        handle.scale = (1.0, 1.0, max(float(np.linalg.norm(d)), 1e-4))

    def show(self, f: DeviceFrame, server: Any) -> None:
        if f.elbow is None or f.wrist is None:
            self.hide()
            return
        for h in (self.elbow, self.wrist, self.fore, self.wrist_cuff, self.prox_cuff):
            h.visible = True
        self.elbow.position = tuple(f.elbow)
        self.wrist.position = tuple(f.wrist)
        self._segment(self.fore, f.elbow, f.wrist)
        axis = f.wrist - f.elbow
        n = float(np.linalg.norm(axis))
        u = axis / n if n > 1e-6 else np.array([1.0, 0.0, 0.0])
        q = tuple(quat_z_to(u))
        prox = f.elbow + f.cuff_to_elbow_m * u
        self.prox_cuff.position = tuple(prox)
        self.prox_cuff.wxyz = q
        self.wrist_cuff.position = tuple(f.wrist)
        self.wrist_cuff.wxyz = q
        if f.anchors is not None:
            a = f.anchors
            self.ropes.points = np.array(
                [[a[0], f.wrist], [a[1], f.wrist], [a[2], prox], [a[3], prox]], dtype=np.float32
            )
            self.ropes.visible = True
        self.floor.position = (float(f.wrist[0]), float(f.wrist[1]), float(f.wrist[2]) - 0.03)
        self.floor.visible = True

        have_sh = f.shoulder is not None
        for h in (self.shoulder, self.upper, self.imu):
            h.visible = have_sh
        if f.shoulder is not None:
            self.shoulder.position = tuple(f.shoulder)
            self.shoulder.color = STATE_RGB.get(f.state, STATE_RGB[None])
            self._segment(self.upper, f.shoulder, f.elbow)
            ua = f.elbow - f.shoulder
            ul = float(np.linalg.norm(ua))
            if ul > 1e-6:
                self.imu.position = tuple(f.elbow - f.imu_to_elbow_m * ua / ul)
                self.imu.wxyz = tuple(quat_x_to(ua))
        pts, cols = trace_segments(f.trace)
        self.trace.points = pts.astype(np.float32)
        self.trace.colors = cols
        self.trace.visible = len(f.trace) > 1

        have_nom = f.nominal is not None
        self.nominal.visible = have_nom
        self.tolerance.visible = have_nom
        if f.nominal is not None:
            self.nominal.position = tuple(f.nominal)
            self.tolerance.position = tuple(f.nominal)
            self.tolerance.scale = f.tolerance_m
        if not self.camera_set:
            centre = f.shoulder if f.shoulder is not None else f.elbow
            look = (centre + f.wrist) / 2.0
            server.initial_camera.look_at = tuple(look)
            server.initial_camera.position = tuple(look + CAMERA_OFFSET)
            for client in server.get_clients().values():
                client.camera.look_at = tuple(look)
                client.camera.position = tuple(look + CAMERA_OFFSET)
            self.camera_set = True


class Viz:
    """The 3D view's server and the newest pose of every device.

    ``update`` and ``configure`` may be called from any thread (the live side's event loop);
    the server thread is viser's own.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, enabled: bool = True) -> None:
        self.host = host
        self.requested_port = port
        self.enabled = enabled
        self._frames: dict[str, DeviceFrame] = {}
        self._selected: str | None = None
        self._server: Any = None
        self._scene: _Scene | None = None
        self._lock = threading.RLock()
        self._shown_version = -1
        self._last_push = 0.0

    # ---- lifecycle -----------------------------------------------------------------------

    @property
    def port(self) -> int | None:
        return int(self._server.get_port()) if self._server is not None else None

    @property
    def running(self) -> bool:
        return self._server is not None

    def start(self) -> int | None:
        """Start the viser server if not yet running; return its port (None if disabled)."""
        if not self.enabled:
            return None
        with self._lock:
            if self._server is None:
                import viser

                server = viser.ViserServer(host=self.host, port=self.requested_port, verbose=False)
                server.gui.configure_theme(
                    show_logo=False,
                    show_share_button=False,
                    control_layout="floating",
                    control_width="small",
                    brand_color=(11, 61, 92),
                )
                # The dashboard explains the scene beside the frame: viser's own control
                # panel (connection, scene tree, dev settings) starts collapsed to a bar.
                server.gui.main_panel.minimize()
                self._server = server
                self._scene = _Scene(server)
                self._scene.hide()
                self._shown_version = -1
                self._push(force=True)
                log.info("3D view (viser) on http://%s:%d", self.host, server.get_port())
            return self.port

    def close(self) -> None:
        with self._lock:
            server, self._server, self._scene = self._server, None, None
        if server is not None:
            try:
                server.stop()
            except Exception:  # shutting down: nothing useful to do with it
                log.exception("stopping the 3D view")

    # ---- what the dashboard and the live side call ----------------------------------------

    @property
    def selected(self) -> str | None:
        return self._selected

    def select(self, device: str | None) -> None:
        """Show ``device`` (one at a time per service)."""
        with self._lock:
            if device == self._selected:
                return
            self._selected = device
            if self._scene is not None:
                self._scene.hide()
            self._shown_version = -1
            self._push(force=True)

    def configure(
        self,
        device: str,
        *,
        tolerance_m: float | None = None,
        cuff_to_elbow_m: float | None = None,
        imu_to_elbow_m: float | None = None,
    ) -> None:
        """The session's parameters (tolerance circle, cuff and IMU placement)."""
        with self._lock:
            f = self._frames.setdefault(device, DeviceFrame())
            if tolerance_m is not None and tolerance_m > 0:
                f.tolerance_m = float(tolerance_m)
            if cuff_to_elbow_m is not None and cuff_to_elbow_m > 0:
                f.cuff_to_elbow_m = float(cuff_to_elbow_m)
            if imu_to_elbow_m is not None and imu_to_elbow_m > 0:
                f.imu_to_elbow_m = float(imu_to_elbow_m)
            f.version += 1
            if device == self._selected:
                self._push(force=True)

    def update(self, device: str, rows: Mapping[str, Sequence[Any]]) -> None:
        """New estimates of ``device``: the rows of a WebSocket ``estimate`` message (parallel
        arrays ``t, elbow_*, shoulder_*, wrist_*, nominal_*, state``; ``None`` where not
        available). Keeps the newest pose and the shoulder trace; redraws at most 30 times
        per second if ``device`` is on screen. Never raises."""
        try:
            self._update(device, rows)
        except Exception:  # the 3D view must never break the live pipeline
            log.exception("3D view update for %s", device)

    def forget(self, device: str) -> None:
        """Drop a device's pose (it went offline or its session ended)."""
        with self._lock:
            self._frames.pop(device, None)
            if device == self._selected and self._scene is not None:
                self._scene.hide()
                self._shown_version = -1

    def frame(self, device: str) -> DeviceFrame | None:
        return self._frames.get(device)

    # ---- internals ----------------------------------------------------------------------

    def _update(self, device: str, rows: Mapping[str, Sequence[Any]]) -> None:
        t = rows.get("t")
        n = len(t) if t is not None else 0
        if n == 0:
            return
        with self._lock:
            f = self._frames.setdefault(device, DeviceFrame())
            states = rows.get("state")
            for i in range(n):
                sh = _point(rows, "shoulder", i)
                st = states[i] if states is not None and i < len(states) else None
                state = st if isinstance(st, str) and st in STATE_RGB else None
                if sh is not None:
                    f.trace.append((float(sh[0]), float(sh[1]), float(sh[2]), state))
            i = n - 1
            f.shoulder = _point(rows, "shoulder", i)
            f.elbow = _point(rows, "elbow", i) if "elbow_x" in rows else f.elbow
            wrist = _point(rows, "wrist", i)
            if wrist is not None:
                f.wrist = wrist
            nominal = _point(rows, "nominal", i)
            if nominal is not None or ("nominal_x" in rows):
                f.nominal = nominal
            f.state = states[i] if states is not None and isinstance(states[i], str) else None
            if f.anchors is None and f.wrist is not None:
                f.anchors = _rope_anchors(f.wrist)
            f.version += 1
            if device == self._selected:
                self._push()

    def _push(self, force: bool = False) -> None:
        """Apply the selected device's newest frame to the scene (lock held)."""
        if self._scene is None or self._selected is None:
            return
        f = self._frames.get(self._selected)
        if f is None or f.version == self._shown_version:
            return
        now = time.monotonic()
        if not force and now - self._last_push < 1.0 / MAX_FPS:
            return
        self._last_push = now
        self._shown_version = f.version
        server = self._server
        with server.atomic():
            self._scene.show(f, server)


def _rope_anchors(wrist: F64) -> F64:
    """Schematic anchors of the robot's ropes, fixed above and beyond the task area: two
    for the wrist cuff, two for the proximal cuff (the real pulleys are device specific)."""
    x, y, z = (float(v) for v in wrist)
    return np.array(
        [
            [x + 0.35, y + 0.30, z + 0.55],
            [x - 0.35, y + 0.30, z + 0.55],
            [x + 0.30, y - 0.20, z + 0.60],
            [x - 0.30, y - 0.20, z + 0.60],
        ]
    )
