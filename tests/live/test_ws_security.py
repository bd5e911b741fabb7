"""Issue 21, WebSockets on a real uvicorn: a login that ends closes its live views (at once
when revoked here, within ``ws_recheck_s`` when revoked elsewhere), foreign Origins are
refused, live views are audited, and overlay tokens stay out of the server's logs."""

from __future__ import annotations

import logging
import sqlite3
from collections.abc import Iterator

import httpx
import pytest
from websockets.sync.client import connect

from backend.settings import Settings
from tests.live.conftest import Service, _service, free_port, wait_for
from tests.live.test_websocket import Listener, refused, ws_url


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    data = tmp_path_factory.mktemp("wssec")
    yield from _service(
        Settings(
            data_dir=data,
            port=free_port(),
            zenoh_listen=f"tcp/127.0.0.1:{free_port()}",
            cookie_secure=False,
            ws_recheck_s=0.5,
        )
    )


def therapist(service: Service, name: str) -> int:
    r = service.api.post("/api/therapists", json={"username": name, "password": "long-enough-pw"})
    assert r.status_code == 201, r.text
    tid: int = r.json()["id"]
    return tid


def token_of(service: Service, name: str, password: str = "long-enough-pw") -> str:
    r = httpx.post(service.url + "/api/auth/login", json={"username": name, "password": password})
    assert r.status_code == 200, r.text
    token: str = r.json()["access_token"]
    return token


def live(service: Service, token: str) -> Listener:
    ws = connect(
        ws_url(service, "/api/ws/live"),
        additional_headers={"Authorization": f"Bearer {token}"},
        open_timeout=10,
    )
    listener = Listener(ws)
    wait_for(lambda: listener.of("hello"), timeout=10, what="hello")
    return listener


def closed_with(listener: Listener, code: int, reason: str | None = None) -> None:
    wait_for(lambda: listener.closed is not None, timeout=10, what="socket closed")
    assert listener.closed is not None
    assert listener.closed[0] == code, listener.closed
    if reason is not None:
        assert listener.closed[1] == reason


def test_logout_password_change_and_deactivation_close_live_views(service: Service) -> None:
    tid = therapist(service, "ws-t1")
    a, b = token_of(service, "ws-t1"), token_of(service, "ws-t1")
    view_a, view_b = live(service, a), live(service, b)
    r = httpx.post(service.url + "/api/auth/logout", headers={"Authorization": f"Bearer {a}"})
    assert r.status_code == 204
    closed_with(view_a, 1008, "logged out")
    assert view_b.closed is None  # the other workstation's login goes on

    c = token_of(service, "ws-t1")
    view_c = live(service, c)
    r = httpx.post(
        service.url + "/api/auth/password",
        json={"current_password": "long-enough-pw", "new_password": "changed-long-pw"},
        headers={"Authorization": f"Bearer {c}"},
    )
    assert r.status_code == 204
    closed_with(view_b, 1008, "password changed")
    assert view_c.closed is None  # the login that changed it goes on

    assert service.api.post(f"/api/therapists/{tid}/deactivate").status_code == 200
    closed_with(view_c, 1008, "account deactivated")
    refused(service, "/api/ws/live", {"Authorization": f"Bearer {c}"})


def test_a_login_revoked_elsewhere_closes_within_the_recheck(service: Service) -> None:
    """Another process (or an operator in the database) revoked it: nothing is pushed here,
    the periodic re-check finds it."""
    therapist(service, "ws-t2")
    token = token_of(service, "ws-t2")
    view = live(service, token)
    with sqlite3.connect(service.data_dir / "rehab.db") as db:
        db.execute(
            "UPDATE logins SET revoked_at = CURRENT_TIMESTAMP WHERE therapist_id = "
            "(SELECT id FROM therapists WHERE username = 'ws-t2')"
        )
    closed_with(view, 1008, "login ended")


def test_foreign_origin_is_refused(service: Service) -> None:
    headers = {"Authorization": f"Bearer {service.token}"}
    refused(service, "/api/ws/live", {**headers, "Origin": "https://evil.example"})
    own = service.url.replace("http://", "http://")  # the service's own origin
    ok = live_with(service, {**headers, "Origin": own})
    ok.close()


def live_with(service: Service, headers: dict[str, str]) -> Listener:
    listener = Listener(connect(ws_url(service, "/api/ws/live"), additional_headers=headers))
    wait_for(lambda: listener.of("hello"), timeout=10, what="hello")
    return listener


def test_live_views_are_audited(service: Service) -> None:
    live(service, service.token).close()
    rows = service.api.get("/api/audit", params={"action": "live.view"}).json()
    assert rows and rows[0]["actor"] == "admin"


def test_overlay_tokens_stay_out_of_the_logs(
    service: Service, caplog: pytest.LogCaptureFixture
) -> None:
    for name in ("uvicorn.access", "uvicorn.error"):  # the fixture runs uvicorn at warning
        logging.getLogger(name).setLevel(logging.INFO)
    secret = "eyJSECRETOVERLAYTOKEN.abc.def"
    with caplog.at_level(logging.INFO):
        httpx.get(service.url + f"/overlay?token={secret}")
        refused(service, f"/api/ws/overlay?token={secret}")
    # the server's lines (httpx, the client here, logs its own request URL)
    joined = "\n".join(r.getMessage() for r in caplog.records if r.name.startswith("uvicorn"))
    assert "/api/ws/overlay?token=" in joined and "/overlay?token=" in joined  # logged...
    assert secret not in joined  # ...without the token


def test_the_3d_view_only_through_the_authenticated_proxy(service: Service) -> None:
    """viser listens on loopback; browsers get its page and its scene stream through
    /api/viz/view/ as a logged-in therapist, and lose the stream with the login."""
    import viser
    from websockets.exceptions import ConnectionClosed
    from websockets.typing import Subprotocol

    assert httpx.get(service.url + "/api/viz/view/").status_code == 401
    info = service.api.get("/api/viz").json()
    assert info["path"] == "/api/viz/view/" and info["port"]
    assert service.app.state.viz.host == "127.0.0.1"
    page = service.api.get("/api/viz/view/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert page.text.lstrip().lower().startswith("<!doctype html")

    protocol = Subprotocol(f"viser-v{viser.__version__}")
    refused(service, "/api/viz/view")  # no login: 1008
    therapist(service, "viz-t1")
    token = token_of(service, "viz-t1")
    ws = connect(
        ws_url(service, "/api/viz/view"),  # where viser's client connects: its page's URL
        additional_headers={"Authorization": f"Bearer {token}"},
        subprotocols=[protocol],
        open_timeout=10,
        max_size=None,
    )
    assert ws.subprotocol == protocol
    first = ws.recv(timeout=10)
    assert isinstance(first, bytes) and first  # viser's scene, msgpack
    r = httpx.post(service.url + "/api/auth/logout", headers={"Authorization": f"Bearer {token}"})
    assert r.status_code == 204
    with pytest.raises(ConnectionClosed) as exc:
        while True:
            ws.recv(timeout=10)
    assert exc.value.rcvd is not None and exc.value.rcvd.code == 1008
    rows = service.api.get("/api/audit", params={"action": "viz.view"}).json()
    assert rows and rows[0]["actor"] == "viz-t1"
