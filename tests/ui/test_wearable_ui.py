"""The wearable session page in a real browser: a simulated two-IMU + camera device (the ROM
test movements) streams over Zenoh into ``rehab serve``; the therapist starts a wearable
session from the device's page, sees the joint-angle plots with their confidence, runs a ROM
test of maximal shoulder flexion and finds its peak in the session's report."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest
from playwright.sync_api import Browser, BrowserContext, Page, expect

from backend.live import lease
from backend.settings import Settings
from simulator import wearable as sw
from simulator.publish import DeviceThread, prepare
from simulator.wearable_moves import rom_duration
from tests.ui.conftest import WS_GATE_JS, ConsoleLog, Service, shot

DEVICE = "wearui01"
PATIENT = "wear-ui"


@pytest.fixture(scope="module")
def context(browser: Browser, service: Service) -> Iterator[BrowserContext]:
    ctx = browser.new_context(base_url=service.url, viewport={"width": 1440, "height": 1400})
    ctx.set_default_timeout(15_000)
    ctx.add_init_script(WS_GATE_JS)
    try:
        yield ctx
    finally:
        ctx.close()


@pytest.fixture(scope="module")
def device(service: Service) -> Iterator[DeviceThread]:
    sim = sw.simulate(
        sw.WearableSimConfig(move="rom", duration_s=rom_duration(), seed=4, device=DEVICE)
    )
    # A worker makes a preview wearable on the first forearm or camera message it gets: the
    # short head (the rest is the session's) waits for a worker to hold the device, whose
    # subscription comes with its lease (the lease may come after the head: seen in CI).
    engine = lease.sync_engine(Settings(data_dir=service.data_dir).db_url)

    def held() -> bool:
        with engine.connect() as conn:
            return DEVICE in lease.held_devices_sync(conn)

    # the start at rest (§8: 2 s, the session's) fast, then the movements in real time
    thread = DeviceThread(
        service.zenoh, prepare(sim.messages), name=DEVICE, head_s=0.3, gated=True,
        fast_until_s=2.0, fast=4.0, ready=held,
    )  # fmt: skip
    thread.start()
    try:
        yield thread
    finally:
        thread.stop()
        engine.dispose()


def test_wearable_session_page(
    context: BrowserContext, service: Service, device: DeviceThread
) -> None:
    console = ConsoleLog()
    api = service.api()
    r = api.post("/api/patients", json={"code": PATIENT, "affected_side": "right"})
    assert r.status_code == 201, r.text
    page: Page = console.watch(context.new_page())
    page.goto("/")
    page.get_by_label("Username").fill(service.username)
    page.get_by_label("Password").fill(service.password)
    page.keyboard.press("Enter")
    expect(page.get_by_role("heading", name="Devices", exact=True)).to_be_visible()
    page.goto(f"/devices/{DEVICE}")
    expect(page.get_by_role("heading", name=DEVICE)).to_be_visible()
    # the preview knows a wearable device by its streams: the joint angles' page
    try:
        expect(page.get_by_role("heading", name="Joint angles")).to_be_visible(timeout=30_000)
    except AssertionError as exc:
        raise AssertionError(f"device thread: sent {device.sent}, error {device.error!r}") from exc
    page.get_by_label("Patient").select_option(label=f"{PATIENT} · right arm · tolerance 10 cm")
    page.get_by_role("button", name="Start session").click()
    expect(page.get_by_role("button", name="Stop session")).to_be_visible()
    sessions = api.get("/api/sessions", params={"device": DEVICE}).json()
    session = next(s for s in sessions if s["status"] == "active")
    assert session["params"]["mode"] == "wearable" and session["params"]["side"] == "right"
    # ROM test: maximal flexion, started before the movements flow (they reach 150° about
    # 3 s after go(): the page's checks took longer than that in a CI run)
    page.get_by_label("Movement").select_option(value="shoulder_flexion")
    page.get_by_role("button", name="Start test").click()
    expect(page.get_by_role("button", name="Stop test: Maximal shoulder flexion")).to_be_visible()
    device.go()
    # the figure follows the flexion (watched from now on: its peak lasts about a second)
    try:
        page.wait_for_function(
            "() => { const e = document.querySelector("
            "'[data-angle=shoulder_flexion_deg] .figure__value');"
            " return e && parseFloat(e.textContent) > 120; }",
            timeout=30_000,
        )
    except Exception:
        shot(page, "wearable-session-failed", full_page=True)
        raise
    figures = page.get_by_test_id("joint-figures")
    expect(figures.locator("[data-angle=shoulder_flexion_deg]")).to_contain_text("°")
    for angle in ("shoulder_flexion_deg", "elbow_flexion_deg", "forearm_pronation_deg"):
        expect(page.locator(f"[data-plot={angle}] canvas")).to_have_count(1)
    page.wait_for_timeout(2500)  # and back down
    shot(page, "wearable-session")
    page.get_by_role("button", name="Stop test: Maximal shoulder flexion").click()
    results = page.get_by_test_id("rom-results")
    expect(results).to_contain_text("Maximal shoulder flexion", timeout=10_000)
    peak_text = results.locator("tbody tr td").nth(1).inner_text()
    peak = float(peak_text.rstrip("°"))
    assert 130.0 < peak < 170.0, peak_text
    # confidence: every figure shown as sure has a ± of at most the threshold
    for el in figures.locator("[data-sure='1']").all():
        hint = el.inner_text()
        assert "±" in hint and "not sure" not in hint, hint
    shot(page, "wearable-rom-test", full_page=True)
    page.get_by_role("button", name="Stop session").click()
    expect(page.get_by_role("link", name="Open the report")).to_be_visible()
    rep = api.get(f"/api/sessions/{session['id']}/report")
    assert rep.status_code == 200, rep.text
    tests = rep.json()["report"]["rom_tests"]
    assert len(tests) == 1 and abs(tests[0]["peak_deg"] - peak) < 0.06, json.dumps(tests)
    assert not console.errors, console.errors
    api.close()
