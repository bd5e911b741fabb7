"""The 3D view's server: lazy start, handles created once, updates only change properties,
bad rows never raise into the live side."""

from __future__ import annotations

import math

import httpx
import numpy as np

from backend.viz import TRACE_POINTS, Viz, quat_x_to, quat_z_to, trace_segments


def rows(t: float, state: str | None = "ok", n: int = 3) -> dict[str, list[float | str | None]]:
    ts = [t + i * 0.04 for i in range(n)]
    return {
        "t": ts,
        "shoulder_x": [0.15] * n, "shoulder_y": [0.0] * n, "shoulder_z": [0.4] * n,
        "elbow_x": [0.2] * n, "elbow_y": [0.2] * n, "elbow_z": [0.2] * n,
        "wrist_x": [0.05] * n, "wrist_y": [0.4] * n, "wrist_z": [0.0] * n,
        "nominal_x": [0.15] * n, "nominal_y": [0.0] * n, "nominal_z": [0.4] * n,
        "state": [state] * n,
    }  # fmt: skip


def test_quaternions_point_the_axes() -> None:
    for d in ([1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.3, -0.4, 0.5], [-1.0, 0.0, 0.0]):
        q = quat_z_to(np.array(d))
        w, x, y, z = q
        # third column of the rotation matrix = R @ e_z
        col = (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))
        n = math.sqrt(sum(v * v for v in d))
        assert all(abs(c - v / n) < 1e-9 for c, v in zip(col, d, strict=True))
        q = quat_x_to(np.array(d))
        w, x, y, z = q
        col = (1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y))
        assert all(abs(c - v / n) < 1e-9 for c, v in zip(col, d, strict=True))


def test_trace_fades_and_keeps_its_shape() -> None:
    pts, cols = trace_segments([(0.0, 0.0, 0.0, "ok"), (0.1, 0.0, 0.0, "outside")])
    assert pts.shape == (TRACE_POINTS - 1, 2, 3) and cols.shape == pts.shape
    assert tuple(cols[-1, 1]) == (0, 114, 178)  # newest point: full blue
    assert cols[-1, 0].sum() > sum((0, 158, 115))  # oldest point: faded towards white


def test_server_handles_created_once() -> None:
    viz = Viz(port=0)
    viz.update("dev", rows(0.0))  # before the server runs: only kept
    assert not viz.running
    port = viz.start()
    try:
        assert port and httpx.get(f"http://127.0.0.1:{port}/", timeout=5).status_code == 200
        viz.select("dev")
        scene = viz._scene
        assert scene is not None
        handles = [id(h) for h in scene.handles]
        for k in range(20):
            viz.update("dev", rows(0.1 * (k + 1), "warning" if k > 10 else "ok"))
        f = viz.frame("dev")
        assert f is not None and f.state == "warning" and len(f.trace) == 63
        viz.update("dev", {"t": [1.0], "shoulder_x": ["bad"], "state": [7]})  # never raises
        viz.update("dev", {"t": []})
        assert [id(h) for h in scene.handles] == handles
        viz.update("dev", rows(3.0))
        viz.configure("dev", tolerance_m=0.08)
        assert np.allclose(scene.tolerance.scale, 0.08)
    finally:
        viz.close()
    assert not viz.running
