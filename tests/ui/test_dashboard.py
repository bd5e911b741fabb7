"""The dashboard, the patient overlay and the report in a real browser, against the real
service with simulated devices (see conftest). The tests of this module run in order and
share one therapist's browser context: log in, create a patient, run a session on a device
that drifts into compensation, watch the indicator and the overlay, stop, read the report,
export; then four devices on one screen at ≥ 20 updates/s."""

from __future__ import annotations

import gzip
import json
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.ui.conftest import ConsoleLog, Service, SimDevice, shot, shot_path

pytest.importorskip("playwright.sync_api", reason="playwright not installed (dev extra)")
from playwright.sync_api import Browser, BrowserContext, Page, Request, expect

DEVICE = "ui01"
PATIENT = "UI-001"
# Calibration (heading convergence) needs ~30-60 s of motion: played 8x faster. Then the
# shoulder drifts out within seconds, stays out for 25 s, and comes back.
LAYOUT = (
    ("rest", 4.0),
    ("proper", 66.0),
    ("transition", 3.0),
    ("compensatory", 25.0),
    ("transition", 4.0),
    ("proper", 60.0),
)
FAST_UNTIL_S = 70.0
GRID_LAYOUT = (("rest", 2.0), ("proper", 150.0))
BLUE, ORANGE = "rgb(0, 114, 178)", "rgb(230, 159, 0)"


@pytest.fixture(scope="module")
def console() -> ConsoleLog:
    return ConsoleLog()


@pytest.fixture(scope="module")
def context(browser: Browser, service: Service) -> Iterator[BrowserContext]:
    ctx = browser.new_context(
        base_url=service.url, viewport={"width": 1440, "height": 1000}, accept_downloads=True
    )
    ctx.set_default_timeout(15_000)
    try:
        yield ctx
    finally:
        ctx.close()


@pytest.fixture(scope="module")
def page(context: BrowserContext, console: ConsoleLog) -> Page:
    return console.watch(context.new_page())


@pytest.fixture(scope="module")
def device(service: Service) -> Iterator[SimDevice]:
    sim = SimDevice(
        service.zenoh, DEVICE, LAYOUT, seed=2, head_s=2.0, fast_until_s=FAST_UNTIL_S, fast=8.0,
        gated=True,
    )  # fmt: skip
    sim.start()
    try:
        yield sim
    finally:
        sim.stop()


@pytest.fixture(scope="module")
def shared() -> dict[str, Any]:
    return {}


def no_console_errors(console: ConsoleLog) -> None:
    errors, console.errors[:] = list(console.errors), []
    assert not errors, "console errors:\n" + "\n".join(errors)


def test_login_with_the_keyboard(page: Page, service: Service, console: ConsoleLog) -> None:
    page.goto("/")
    expect(page.get_by_role("heading", name="Rehab dashboard")).to_be_visible()
    # The username field has the focus; Tab to the password; Enter submits.
    page.keyboard.type(service.username)
    page.keyboard.press("Tab")
    page.keyboard.type("wrong-password")
    page.keyboard.press("Enter")
    expect(page.get_by_role("alert")).to_contain_text("invalid username or password")
    console.errors.clear()  # the browser logs the refused login (401) itself
    page.get_by_label("Password").fill(service.password)
    page.keyboard.press("Enter")
    expect(page.get_by_role("heading", name="Devices", exact=True)).to_be_visible()
    no_console_errors(console)


def test_keyboard_navigation(page: Page, console: ConsoleLog) -> None:
    page.goto("/")
    expect(page.get_by_role("heading", name="Devices", exact=True)).to_be_visible()
    page.locator("body").focus()
    seen: list[str] = []
    for _ in range(8):
        page.keyboard.press("Tab")
        seen.append(page.evaluate("document.activeElement.textContent.trim()"))
        if seen[-1] == "Patients":
            break
    assert seen[0] == "Skip to content", seen
    assert seen[-1] == "Patients", seen
    # The focus ring is visible (an outline of at least 2 px).
    outline = page.evaluate("getComputedStyle(document.activeElement).outlineWidth")
    assert float(outline.removesuffix("px")) >= 2
    page.keyboard.press("Enter")
    expect(page).to_have_url(re.compile(r"/patients$"))
    expect(page.get_by_role("heading", name="Patients", exact=True)).to_be_focused()
    no_console_errors(console)


def test_create_patient(page: Page, console: ConsoleLog, shared: dict[str, Any]) -> None:
    page.goto("/patients")
    page.get_by_role("button", name="New patient").click()
    page.get_by_label("Pseudonymous code").fill(PATIENT)
    page.get_by_text("Left", exact=True).click()
    page.get_by_role("button", name="Create patient").click()
    expect(page.get_by_role("heading", name=f"Patient {PATIENT}")).to_be_visible()
    shared["patient_url"] = page.url
    no_console_errors(console)


def _indicator_states(page: Page, until: set[str], timeout_s: float) -> list[str]:
    """The indicator's states as they change, until one of ``until`` shows up."""
    seen: list[str] = []
    deadline = time.monotonic() + timeout_s
    ind = page.locator(".live-indicator .indicator")
    while time.monotonic() < deadline:
        state = ind.get_attribute("data-state")
        if state and (not seen or seen[-1] != state):
            seen.append(state)
        if state in until:
            return seen
        page.wait_for_timeout(50)
    raise AssertionError(f"indicator never reached {until}: {seen}")


def test_session_indicator_and_overlay(
    page: Page,
    context: BrowserContext,
    device: SimDevice,
    console: ConsoleLog,
    shared: dict[str, Any],
) -> None:
    page.goto(f"/devices/{DEVICE}")
    expect(page.get_by_role("heading", name=DEVICE)).to_be_visible()
    expect(page.locator(".page__head .online--yes")).to_be_visible(timeout=20_000)
    page.get_by_label("Patient").select_option(label=f"{PATIENT} · left arm · tolerance 10 cm")
    page.get_by_role("button", name="Start session").click()
    expect(page.get_by_role("button", name="Stop session")).to_be_visible()
    # Until the heading converges the therapist is told to have the arm moved.
    expect(page.get_by_role("heading", name="Move the arm")).to_be_visible()
    expect(page.get_by_role("progressbar")).to_be_visible()
    device.go()
    expect(page.get_by_role("heading", name="Calibrated")).to_be_visible(timeout=45_000)
    expect(page.get_by_role("button", name="Set nominal shoulder here")).to_be_enabled()
    assert device.error is None, device.error

    # The patient's screen, through its scoped link.
    page.get_by_role("button", name="Patient screen link").click()
    link = page.get_by_label("Overlay link for the patient's screen").input_value()
    assert "/overlay?token=" in link
    overlay = console.watch(context.new_page())
    overlay.set_viewport_size({"width": 1280, "height": 720})
    overlay.goto(link)
    page.bring_to_front()

    # Inside first, then outside (blue marker), then the warning (orange background).
    states = _indicator_states(page, {"ok"}, 20)
    states += _indicator_states(page, {"outside", "warning"}, 30)
    if states[-1] == "outside":
        marker = page.locator(".live-indicator .ind-marker g:visible .ind-shape")
        assert marker.get_attribute("fill", timeout=2000) == "#0072B2"
        label = page.locator(".live-indicator .indicator__label")
        expect(label).to_have_text(re.compile("Outside"))
    states += _indicator_states(page, {"warning"}, 20)
    assert "outside" in states and states.index("outside") < states.index("warning"), states
    expect(page.locator(".live-indicator .indicator__label")).to_have_text(re.compile("Warning"))
    page.wait_for_function(
        "c => getComputedStyle(document.querySelector('.live-indicator .ind-bg')).fill === c",
        arg=ORANGE,
        timeout=3000,
    )
    page.wait_for_timeout(300)
    shot(page, "dashboard", full_page=True)

    # A compensatory cycle: the overlay tells the patient and pauses the game.
    expect(overlay.locator("body")).to_have_attribute("data-paused", "true", timeout=30_000)
    warning = overlay.locator("#overlay-warning")
    expect(warning).to_be_visible()
    expect(warning).to_contain_text("starting position")
    expect(overlay.locator(".ov-indicator .indicator")).to_have_attribute(
        "data-state", re.compile("outside|warning")
    )
    shot(overlay, "overlay")
    expect(page.get_by_text(re.compile(r"✗ [1-9]\d* compensatory"))).to_be_visible()
    expect(page.locator("tr.row--comp").first).to_contain_text("Compensatory")
    # Back inside the tolerance: the game goes on.
    expect(overlay.locator("body")).to_have_attribute("data-paused", "false", timeout=45_000)
    shot(overlay, "overlay-resumed")
    overlay.close()

    # The embedded 3D view (viser, its own port) draws the arm.
    viz = page.locator(".viz")
    viz.scroll_into_view_if_needed()
    expect(page.frame_locator(".viz__frame").locator("canvas").first).to_be_visible(timeout=20_000)
    page.wait_for_timeout(2500)
    viz.screenshot(path=str(shot_path("dashboard-3d")))
    assert device.error is None, device.error
    no_console_errors(console)


def test_report_and_export(page: Page, console: ConsoleLog) -> None:
    page.get_by_role("button", name="Stop session").click()
    page.get_by_role("link", name="Open the report").click()
    expect(page.get_by_role("heading", name=re.compile("Session report"))).to_be_visible()
    figures = page.get_by_label("Summary")
    expect(figures).to_contain_text(re.compile(r"[1-9]\d* of \d+"))  # compensatory cycles
    for plot in ("report-displacement", "report-elbow", "report-cycles"):
        expect(page.locator(f"[data-plot={plot}] canvas")).to_be_visible(timeout=20_000)
    expect(page.locator("table tbody tr").first).to_be_visible()
    expect(page.get_by_role("heading", name="Data quality")).to_be_visible()
    page.wait_for_timeout(300)
    shot(page, "report", full_page=True)

    with page.expect_download() as dl:
        page.locator("[data-export=csv]").click()
    text = Path(dl.value.path()).read_text(encoding="utf-8")
    assert text.startswith("t,elbow_x,elbow_y,elbow_z,shoulder_x"), text[:100]
    assert dl.value.suggested_filename.endswith(".csv")
    with page.expect_download() as dl:
        page.locator("[data-export=json]").click()
    assert '"cycles"' in Path(dl.value.path()).read_text(encoding="utf-8")
    with page.expect_download() as dl:
        page.locator("[data-export=recording]").click()
    first = gzip.decompress(Path(dl.value.path()).read_bytes()).splitlines()[0]
    assert json.loads(first)["key"].startswith(f"rehab/{DEVICE}/"), first[:100]
    no_console_errors(console)


def test_patient_history(
    page: Page, service: Service, console: ConsoleLog, shared: dict[str, Any]
) -> None:
    def exports() -> list[dict[str, Any]]:
        api = service.api()
        try:
            audit: list[dict[str, Any]] = api.get("/api/audit", params={"limit": 1000}).json()
        finally:
            api.close()
        return [a for a in audit if a["action"].startswith("export.")]

    # The history reads the sessions list only: no report is fetched, nothing is audited.
    before = exports()
    reports: list[str] = []

    def on_request(r: Request) -> None:
        if "/report" in r.url:
            reports.append(r.url)

    page.on("request", on_request)
    page.goto(shared["patient_url"])
    expect(page.get_by_role("heading", name="Trends across sessions")).to_be_visible()
    for plot in ("trend-compensatory", "trend-elbow", "trend-shoulder"):
        expect(page.locator(f"[data-plot={plot}] canvas")).to_be_visible(timeout=15_000)
    expect(page.get_by_role("link", name="Report")).to_be_visible()
    sessions = page.get_by_role("table", name=re.compile(f"Sessions of patient {PATIENT}"))
    row = sessions.locator("tbody tr").first
    headers = [h.strip() for h in sessions.locator("thead th").all_inner_texts()]
    cell = {h: row.locator("td").nth(i) for i, h in enumerate(headers) if h}
    for name in ("Elbow range", "Elevation range", "Azimuth range"):
        expect(cell[name]).to_have_text(re.compile(r"^\d+°$"))
    expect(cell["Compensatory"]).to_have_text(re.compile(r"^[1-9]\d* %$"))
    expect(cell["Shoulder displacement (median / p95)"]).to_have_text(
        re.compile(r"^\d+\.\d cm / \d+\.\d cm$")
    )
    expect(page.get_by_label("Last session")).to_contain_text(re.compile(r"Elbow range.*\d+°"))
    shot(page, "patient-history", full_page=True)
    page.remove_listener("request", on_request)
    assert not reports, reports
    assert exports() == before

    # The tolerated time outside can be adaptive (a share of the last cycle), by keyboard.
    page.get_by_role("button", name="Edit").focus()
    page.keyboard.press("Enter")
    page.get_by_label(re.compile("^Adaptive")).focus()
    page.keyboard.press("Space")
    expect(page.get_by_label("Warning after (s)")).to_be_disabled()
    page.get_by_role("button", name="Save changes").focus()
    page.keyboard.press("Enter")
    expect(page.locator(".page__head")).to_contain_text("20 % of the last cycle (adaptive)")
    no_console_errors(console)


def test_four_devices_at_20_updates_per_second(
    page: Page, service: Service, console: ConsoleLog
) -> None:
    names = [f"grid{i}" for i in range(1, 5)]
    sims = [
        SimDevice(service.zenoh, n, GRID_LAYOUT, seed=10 + i, head_s=0, fast_until_s=60, fast=8)
        for i, n in enumerate(names)
    ]
    for s in sims:
        s.start()
    try:
        page.goto(f"/grid?devices={','.join(names)}")
        for n in names:
            cell = page.locator(f".grid-cell[data-device={n}]")
            expect(cell.locator(".online--yes")).to_be_visible(timeout=20_000)
        # Calibrated (the first minute is played 8x faster), then real time.
        for n in names:
            cell = page.locator(f".grid-cell[data-device={n}] .indicator")
            expect(cell).not_to_have_attribute("data-state", "waiting", timeout=30_000)
        page.wait_for_timeout(1500)
        before = page.evaluate("structuredClone(window.__rehabLive.frames)")
        t0 = time.monotonic()
        page.wait_for_timeout(5000)
        after = page.evaluate("structuredClone(window.__rehabLive.frames)")
        dt = time.monotonic() - t0
        rates = {n: (after.get(n, 0) - before.get(n, 0)) / dt for n in names}
        print(f"dashboard updates/s with four devices: {rates}")
        shot(page, "grid", full_page=True)
        assert all(r >= 20 for r in rates.values()), rates
    finally:
        for s in sims:
            s.stop()
    no_console_errors(console)
