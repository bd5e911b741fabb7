"""How the backend serves the built front end (``backend/static.py``): pages, hashed assets,
the fallback that never shadows the API, and a Content-Security-Policy that lets nothing
load from another host. A stand-in ``dist`` in a temp dir: no build, no browser needed."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.static import content_security_policy, install_frontend


@pytest.fixture
def dist(tmp_path: Path) -> Path:
    (tmp_path / "assets").mkdir()
    (tmp_path / "index.html").write_text("<!doctype html><title>dashboard</title>")
    (tmp_path / "overlay.html").write_text("<!doctype html><title>overlay</title>")
    (tmp_path / "assets" / "index-abc123.js").write_text("console.log(1)")
    (tmp_path / "favicon.svg").write_text("<svg/>")
    return tmp_path


@pytest.fixture
def client(dist: Path) -> TestClient:
    app = FastAPI()

    @app.get("/api/ping")
    def ping() -> dict[str, bool]:
        return {"ok": True}

    install_frontend(app, dist)
    return TestClient(app, base_url="http://clinic-pc.local:8000")


def directives(csp: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for part in csp.split(";"):
        name, *sources = part.split()
        out[name] = sources
    return out


def test_pages_carry_a_self_only_policy(client: TestClient) -> None:
    for path, title in (("/", "dashboard"), ("/devices/ui01", "dashboard"),
                        ("/sessions/3", "dashboard"), ("/overlay", "overlay")):  # fmt: skip
        r = client.get(path)
        assert r.status_code == 200 and title in r.text, path
        assert r.headers["cache-control"] == "no-cache"
        assert r.headers["referrer-policy"] == "no-referrer"  # the overlay URL holds a token
        d = directives(r.headers["content-security-policy"])
        for name in ("default-src", "script-src", "connect-src", "base-uri", "form-action"):
            assert d[name] == ["'self'"], (name, d[name])
        assert d["style-src"] == ["'self'", "'unsafe-inline'"]
        assert d["object-src"] == ["'none'"]
        assert d["frame-ancestors"] == ["'self'"]
        # Frames (the 3D view, on its own port): this host only, never another one.
        assert d["frame-src"] == [
            "'self'",
            "http://clinic-pc.local:*",
            "https://clinic-pc.local:*",
        ]
        for sources in d.values():
            for src in sources:
                assert (
                    src.startswith("'") or src in {"data:", "blob:"} or ("clinic-pc.local" in src)
                ), src


@pytest.mark.parametrize(
    "host", [None, "", "::1", "evil.example/x", "a b", "*", "x..y", "-bad-", "host:*"]
)
def test_odd_hosts_get_frames_from_self_only(host: str | None) -> None:
    d = directives(content_security_policy(host))
    assert d["frame-src"] == ["'self'"], d["frame-src"]


def test_plain_hosts_name_themselves() -> None:
    for host in ("127.0.0.1", "localhost", "Rehab-PC.clinic.example"):
        d = directives(content_security_policy(host))
        assert d["frame-src"] == ["'self'", f"http://{host}:*", f"https://{host}:*"]


def test_assets_are_cached_for_good_and_missing_ones_are_404(client: TestClient) -> None:
    r = client.get("/assets/index-abc123.js")
    assert r.status_code == 200
    assert r.headers["cache-control"] == "public, max-age=31536000, immutable"
    r = client.get("/assets/index-missing.js")
    assert r.status_code == 404 and "dashboard" not in r.text
    r = client.get("/favicon.svg")
    assert r.status_code == 200 and r.text == "<svg/>"


def test_the_fallback_never_shadows_the_api(client: TestClient) -> None:
    assert client.get("/api/ping").json() == {"ok": True}
    r = client.get("/api/nothing-here")
    assert r.status_code == 404
    assert r.headers["content-type"].startswith("application/json")
    r = client.post("/devices/ui01")
    assert r.status_code in {404, 405} and "dashboard" not in r.text
    r = client.get("/index.html/../../etc/passwd")
    assert "root:" not in r.text


def test_not_built_says_how_to_build(tmp_path: Path) -> None:
    app = FastAPI()
    install_frontend(app, tmp_path / "missing")
    r = TestClient(app).get("/")
    assert r.status_code == 503 and "frontend/build.sh" in r.text
