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
from urllib.parse import urlsplit

import pytest

from tests.ui.conftest import (
    WS_GATE_JS,
    ConsoleLog,
    Service,
    SimDevice,
    colour_pixels,
    contrast_ratio,
    hold_when,
    shot,
    shot_held,
    shot_while,
)

pytest.importorskip("playwright.sync_api", reason="playwright not installed (dev extra)")
from playwright.sync_api import Browser, BrowserContext, Page, Request, expect

DEVICE = "ui01"
PATIENT = "UI-001"
# Calibration (heading convergence) needs ~30-60 s of motion: played 8x faster. Then the
# shoulder drifts out within seconds, compensates for 40 s (out in every cycle: the
# dashboard's warning and the overlay's pause come again and again, so screenshots can wait
# for them), and comes back.
LAYOUT = (
    ("rest", 4.0),
    ("proper", 66.0),
    ("transition", 3.0),
    ("compensatory", 40.0),
    ("transition", 4.0),
    ("proper", 60.0),
)
FAST_UNTIL_S = 70.0
GRID_LAYOUT = (("rest", 2.0), ("proper", 150.0))
GRID = [f"grid{i}" for i in range(1, 5)]
BAD_DEVICE = "grid2"  # gets one malformed message: its data-quality badge says so
BLUE, ORANGE = "rgb(0, 114, 178)", "rgb(230, 159, 0)"
# Series colours of the charts (frontend/src/lib/plots.ts, Okabe-Ito).
DISP, ELBOW, ELEV, AZIM, COMP = "#0072B2", "#CC79A7", "#D55E00", "#56B4E9", "#E69F00"
# What the indicator shows in each state, readable without colour: a text label, an icon
# and a marker shape of its own (none while waiting), and the paper's colours.
INDICATOR = {
    "waiting": {"label": "Waiting", "icon": "…", "shape": None, "fill": None},
    "ok": {"label": "OK", "icon": "✓", "shape": "circle", "fill": "#009E73"},
    "outside": {"label": "Outside", "icon": "◆", "shape": "rect", "fill": "#0072B2"},
    "warning": {"label": "Warning", "icon": "▲", "shape": "path", "fill": "#0072B2"},
}
INDICATOR_JS = """(root) => {
    const r = document.querySelector(root);
    if (!r) return null;
    const marker = r.querySelector(".ind-marker");
    const g = [...marker.children].find((x) => x.style.display !== "none");
    const shape = marker.style.display !== "none" && g ? g.querySelector(".ind-shape") : null;
    return {
        state: r.dataset.state,
        label: r.querySelector(".indicator__text").textContent,
        icon: r.querySelector(".indicator__icon").textContent,
        sub: r.querySelector(".indicator__sub").textContent,
        shape: shape ? shape.tagName : null,
        fill: shape ? shape.getAttribute("fill") : null,
        bg: r.querySelector(".ind-bg").getAttribute("class"),
    };
}"""


@pytest.fixture(scope="module")
def console() -> ConsoleLog:
    return ConsoleLog()


@pytest.fixture(scope="module")
def context(browser: Browser, service: Service) -> Iterator[BrowserContext]:
    ctx = browser.new_context(
        base_url=service.url, viewport={"width": 1440, "height": 1000}, accept_downloads=True
    )
    ctx.set_default_timeout(15_000)
    ctx.add_init_script(WS_GATE_JS)  # lets a screenshot hold the live feed still
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
        sim.wait_known(service)  # the tests open its page as a device that is online
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
    assert "Devices" in seen, seen  # the nav link before it
    # The focus ring is visible (an outline of at least 2 px).
    outline = page.evaluate("getComputedStyle(document.activeElement).outlineWidth")
    assert float(outline.removesuffix("px")) >= 2
    page.keyboard.press("Enter")
    expect(page).to_have_url(re.compile(r"/patients$"))
    expect(page.get_by_role("heading", name="Patients", exact=True)).to_be_focused()
    # The skip link jumps over the navigation: the next Tab lands in the page itself.
    page.reload()
    expect(page.get_by_role("heading", name="Patients", exact=True)).to_be_visible()
    page.keyboard.press("Tab")
    expect(page.get_by_role("link", name="Skip to content")).to_be_focused()
    page.keyboard.press("Enter")
    page.keyboard.press("Tab")
    assert page.evaluate("!!document.activeElement.closest('main')"), page.evaluate(
        "document.activeElement.outerHTML"
    )
    expect(page.get_by_role("button", name="New patient")).to_be_focused()
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


def _indicator_states(
    page: Page, until: set[str], timeout_s: float, views: dict[str, dict[str, Any]]
) -> list[str]:
    """The indicator's states as they change, until one of ``until`` shows up; what it
    showed in each state goes to ``views`` (state -> label, icon, marker shape, colours)."""
    seen: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        view = page.evaluate(INDICATOR_JS, ".live-indicator .indicator")
        state = view["state"] if view else None
        if state and (not seen or seen[-1] != state):
            seen.append(state)
            views.setdefault(state, view)
        if state in until:
            return seen
        page.wait_for_timeout(50)
    raise AssertionError(f"indicator never reached {until}: {seen}")


def _check_indicator_view(state: str, view: dict[str, Any]) -> None:
    want = INDICATOR[state]
    assert view["label"] == want["label"], (state, view)
    assert view["icon"] == want["icon"], (state, view)
    assert view["shape"] == want["shape"], (state, view)
    assert view["fill"] == want["fill"], (state, view)
    assert view["sub"].strip(), (state, view)  # a sentence under the label, in every state
    assert view["bg"] == f"ind-bg ind-bg--{state}", (state, view)  # orange: warning only


def _overlay_readability(overlay: Page, banner: bool = True) -> None:
    """Readable from 2 m: type sized to the screen, AAA contrast, the indicator in the
    lower right corner."""
    m = overlay.evaluate(
        """() => {
        const bgOf = (e) => {
            for (; e; e = e.parentElement) {
                const c = getComputedStyle(e).backgroundColor;
                if (c && c !== "transparent" && !/^rgba\\(.*,\\s*0\\)$/.test(c)) return c;
            }
            return "rgb(255, 255, 255)";
        };
        const css = (sel) => {
            const e = document.querySelector(sel);
            if (!e || !e.getClientRects().length) return null;  // not shown
            const s = getComputedStyle(e);
            return { px: parseFloat(s.fontSize), fg: s.color, bg: bgOf(e), text: e.textContent };
        };
        const box = document.querySelector(".ov-indicator").getBoundingClientRect();
        return {
            vw: innerWidth, vh: innerHeight,
            title: css(".ov-banner__title"), text: css(".ov-banner__text"),
            status: css(".ov-banner__status"), hint: css(".ov-hint"),
            label: css(".ov-indicator .indicator__label"),
            sub: css(".ov-indicator .indicator__sub"),
            score: css(".ov-score"),
            box: { left: box.left, right: box.right, top: box.top, bottom: box.bottom },
        };
    }"""
    )
    vh, vw = m["vh"], m["vw"]
    if banner:
        assert m["title"] and m["text"] and m["status"], m
    else:
        assert m["hint"] and m["hint"]["text"], m  # what to do now, e.g. "Collect the stars"
    for name, share in (("title", 0.06), ("text", 0.04), ("status", 0.03), ("hint", 0.04),
                        ("label", 0.04), ("score", 0.05), ("sub", 0.03)):  # fmt: skip
        if m[name] is None:
            continue
        px = m[name]["px"]
        assert px >= share * vh, f"{name}: {px}px < {share:.0%} of {vh}px ({m[name]['text']!r})"
        ratio = contrast_ratio(m[name]["fg"], m[name]["bg"])
        assert ratio >= 7, f"{name}: contrast {ratio:.1f} < 7 ({m[name]})"
    box = m["box"]
    assert box["right"] >= 0.95 * vw and box["bottom"] >= 0.9 * vh, box
    assert box["left"] >= 0.6 * vw and box["top"] >= 0.3 * vh, box


def test_a_device_not_heard_from_yet_is_waited_for(page: Page, console: ConsoleLog) -> None:
    page.goto("/devices/later01")
    expect(page.get_by_role("heading", name="later01")).to_be_visible()
    expect(page.get_by_role("status").filter(has_text="has not sent data yet")).to_be_visible()
    expect(page.get_by_role("alert")).to_have_count(0)  # not an error
    # The browser itself logs the 404 of the device's REST resource; nothing else.
    assert len(console.errors) == 1 and "/api/devices/later01]" in console.errors[0], console.errors
    console.errors.clear()


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
    views: dict[str, dict[str, Any]] = {}
    waiting = page.evaluate(INDICATOR_JS, ".live-indicator .indicator")
    assert waiting["state"] == "waiting", waiting
    _check_indicator_view("waiting", waiting)
    assert waiting["sub"] == "Move the arm: calibrating", waiting
    device.go()
    expect(page.get_by_role("heading", name="Calibrated")).to_be_visible(timeout=45_000)
    expect(page.get_by_role("button", name="Set nominal shoulder here")).to_be_enabled()
    assert device.error is None, device.error

    # The patient's screen, through its scoped link.
    page.get_by_role("button", name="Patient screen link").click()
    link = page.get_by_label("Overlay link for the patient's screen").input_value()
    assert "/overlay#token=" in link  # after "#": in no request line
    overlay = console.watch(context.new_page())
    overlay.set_viewport_size({"width": 1280, "height": 720})
    sockets: list[str] = []
    overlay.on("websocket", lambda ws: sockets.append(ws.url))
    overlay.goto(link)
    page.bring_to_front()

    # Inside first, then outside (blue marker), then the warning (orange background).
    states = _indicator_states(page, {"ok"}, 20, views)
    states += _indicator_states(page, {"outside", "warning"}, 30, views)
    states += _indicator_states(page, {"warning"}, 20, views)
    assert "outside" in states and states.index("outside") < states.index("warning"), states
    for state in ("ok", "outside", "warning"):
        _check_indicator_view(state, views[state])
    expect(page.locator(".live-indicator .indicator__label")).to_have_text(re.compile("Warning"))
    warning_js = (
        "document.querySelector('.live-indicator .indicator').dataset.state === 'warning' && "
        f"getComputedStyle(document.querySelector('.live-indicator .ind-bg')).fill === '{ORANGE}'"
    )
    page.wait_for_function(f"() => {warning_js}", timeout=3000)
    hold_when(page, warning_js)  # the dashboard keeps showing the warning for its screenshot

    # the overlay's feed took its token from the first message, not from its URL
    assert sockets and all("token" not in u for u in sockets), sockets

    # A compensatory cycle: the overlay tells the patient and pauses the game.
    overlay.bring_to_front()
    warning = overlay.locator("#overlay-warning")

    def paused_overlay() -> None:
        expect(warning).to_be_visible()
        expect(warning).to_contain_text("Please stop")
        expect(warning).to_contain_text("Move your shoulder back to the starting position")
        _overlay_readability(overlay)

    # While paused it says whether the shoulder is back yet (the verdict comes at the end of
    # a cycle: the shoulder may be back already).
    paused = """document.body.dataset.paused === 'true' && (() => {
        const state = document.querySelector('.ov-indicator .indicator').dataset.state;
        const status = document.querySelector('.ov-banner__status').textContent;
        return state === 'ok' ? status.includes('It is back')
            : /outside|warning/.test(state) && status.includes('goes on when it is back');
    })()"""
    shot_while(overlay, "overlay", paused, timeout_s=40, during=paused_overlay)

    # The dashboard's screenshot, of the warning it was held at. The whole page in view:
    # chromium does not draw a cross-origin frame out of view (the 3D view), so a full-page
    # screenshot would show it blank. Only now: the software-rendered 3D view is heavy here.
    page.bring_to_front()
    height = page.evaluate("document.documentElement.scrollHeight")
    page.set_viewport_size({"width": 1440, "height": height})
    page.wait_for_timeout(3000)  # the 3D view draws (and fades in) once in view
    shot_held(page, "dashboard", warning_js, full_page=True)
    page.set_viewport_size({"width": 1440, "height": 1000})
    expect(page.get_by_text(re.compile(r"✗ [1-9]\d* compensatory"))).to_be_visible()
    expect(page.locator("tr.row--comp").first).to_contain_text("Compensatory")
    # Back inside the tolerance: the game goes on.
    overlay.bring_to_front()
    resumed = (
        "document.body.dataset.paused === 'false' && "
        "document.querySelector('.ov-indicator .indicator').dataset.state === 'ok'"
    )

    def resumed_overlay() -> None:
        expect(overlay.locator("#overlay-warning")).to_be_hidden()
        _overlay_readability(overlay, banner=False)

    shot_while(overlay, "overlay-resumed", resumed, timeout_s=60, during=resumed_overlay)
    shared["overlay"] = overlay  # open until the session ends (test_report_and_export)
    page.bring_to_front()

    # The embedded 3D view (viser, its own port) draws the arm.
    viz = page.locator(".viz")
    viz.scroll_into_view_if_needed()
    expect(page.frame_locator(".viz__frame").locator("canvas").first).to_be_visible(timeout=20_000)
    page.wait_for_timeout(2500)
    # The page held still (new cycles would move the section down); the 3D view goes on.
    hold_when(page, "true")
    shot_held(page, "dashboard-3d", "true", locator=viz)

    # The nominal shoulder: set here with one click, and back to automatic with one click.
    calib = page.locator(".calib")
    page.get_by_role("button", name="Set nominal shoulder here").click()
    expect(calib).to_contain_text(re.compile(r"Nominal shoulder set here by \w+"))
    page.get_by_role("button", name="Reset to automatic").click()
    expect(calib).to_contain_text(re.compile(r"Nominal shoulder (set automatically|not set yet)"))
    assert device.error is None, device.error
    no_console_errors(console)


def test_report_and_export(page: Page, console: ConsoleLog, shared: dict[str, Any]) -> None:
    # By keyboard: stop the session, then follow the link to its report.
    page.get_by_role("button", name="Stop session").focus()
    page.keyboard.press("Enter")
    # The patient's screen says the session is over (and stops trying: the link is dead).
    overlay: Page = shared.pop("overlay")
    ended = overlay.locator("#overlay-warning[data-kind=ended]")
    expect(ended).to_be_visible()
    expect(ended).to_contain_text("The session has ended")
    expect(overlay.locator(".ov-hint")).not_to_have_text("Connecting…")
    overlay.wait_for_timeout(1500)  # a reconnection would be refused, and logged, by now
    overlay.close()
    page.bring_to_front()
    page.get_by_role("link", name="Open the report").focus()
    page.keyboard.press("Enter")
    expect(page.get_by_role("heading", name=re.compile("Session report"))).to_be_visible()

    # Summary first: one to three key figures, before everything else on the page.
    figures = page.get_by_label("Summary")
    expect(figures).to_contain_text(re.compile(r"[1-9]\d* of \d+"))  # compensatory cycles
    n_figures = figures.locator(".figure").count()
    assert 1 <= n_figures <= 3, n_figures
    order = page.evaluate(
        """() => [...document.querySelectorAll("main .page > *")].map((e) =>
            e.getAttribute("aria-label") || e.getAttribute("aria-labelledby") || e.className)"""
    )
    assert order[1] == "Summary", order  # right after the page's title
    assert (
        order.index("plots-title") < order.index("cycles-title") < order.index("quality-title")
    ), order

    # Plots drawn, with their series (not just axes).
    for plot, colour in (("report-displacement", DISP), ("report-elbow", ELBOW),
                         ("report-arm", ELEV), ("report-arm", AZIM),
                         ("report-cycles", COMP)):  # fmt: skip
        expect(page.locator(f"[data-plot={plot}] canvas")).to_be_visible(timeout=20_000)
        drawn = colour_pixels(page, f"[data-plot={plot}] canvas", colour)
        assert drawn > 50, (plot, drawn)

    # The cycle table holds every cycle, with its verdict.
    total = int(
        re.search(r"of (\d+)", figures.locator(".figure").first.inner_text()).group(1)  # type: ignore[union-attr]
    )
    cycles = page.get_by_role("region", name="Cycles with their verdicts")
    expect(cycles.locator("tbody tr")).to_have_count(total)
    expect(cycles.locator("tbody tr.row--comp").first).to_contain_text("Compensatory")
    expect(cycles.locator("tbody tr").first).to_contain_text(re.compile("Proper|Compensatory"))

    # Data quality: the counters, in words.
    quality = page.locator("section[aria-labelledby=quality-title]")
    expect(quality.get_by_role("heading", name="Data quality")).to_be_visible()
    imu = quality.locator("dt", has_text="IMU samples").locator("xpath=following-sibling::dd")
    assert int(imu.inner_text().replace(",", "")) > 1000

    # Range of motion in anatomical terms, with the note that the robot stands in for the
    # trunk; movement quality per cycle with the session medians; the wrist paths.
    rom = page.locator("section[aria-labelledby=rom-title]")
    expect(rom.locator("[data-table=rom] tbody tr")).to_have_count(4)
    expect(rom.locator("[data-table=rom]")).to_contain_text("Shoulder plane of elevation")
    expect(rom.locator("[data-table=rom] tbody tr").nth(1)).to_contain_text(re.compile(r"\d+°"))
    expect(rom.locator("[data-note=frame]")).to_contain_text("stands in for the trunk")
    rom.locator("summary").click()  # per cycle, folded by default
    expect(rom.locator("[data-table=rom-cycles] tbody tr")).to_have_count(total)
    mq = page.locator("section[aria-labelledby=mq-title]")
    expect(mq.locator("[data-table=movement-quality] tbody tr")).to_have_count(total + 1)
    expect(mq.locator("[data-median=sparc]")).to_have_text(re.compile(r"^-\d+\.\d\d$"))
    expect(mq.locator("[data-plot=report-sparc] canvas")).to_be_visible(timeout=20_000)
    assert colour_pixels(page, "[data-plot=report-sparc] canvas", DISP) > 50
    paths = mq.locator("[data-plot=wrist-paths] svg polyline")
    expect(paths).to_have_count(total)
    assert mq.locator("polyline[data-verdict=compensatory]").count() >= 1
    assert mq.locator("polyline[data-verdict=proper]").count() >= 1
    mq.scroll_into_view_if_needed()
    shot(page, "report-movement-quality")

    # Seven exports, each a real link a keyboard reaches.
    exports = page.locator("[data-export]")
    expect(exports).to_have_count(7)
    assert [e.get_attribute("data-export") for e in exports.all()] == [
        "json", "csv", "details", "recording", "pdf", "fhir", "mcap"
    ]  # fmt: skip
    expect(page.get_by_role("link", name="Report (JSON)")).to_be_visible()
    expect(page.get_by_role("link", name="Estimates (CSV)")).to_be_visible()
    expect(page.get_by_role("link", name="Details (CSV)")).to_be_visible()
    expect(page.get_by_role("link", name="Raw recording")).to_be_visible()
    expect(page.get_by_role("link", name="Report (PDF)")).to_be_visible()
    page.wait_for_timeout(300)
    shot(page, "report", full_page=True)

    with page.expect_download() as dl:
        page.locator("[data-export=csv]").click()
    text = Path(dl.value.path()).read_text(encoding="utf-8")
    assert text.startswith("t,elbow_x,elbow_y,elbow_z,shoulder_x"), text[:100]
    assert dl.value.suggested_filename.endswith(".csv")
    with page.expect_download() as dl:
        page.locator("[data-export=details]").click()
    text = Path(dl.value.path()).read_text(encoding="utf-8")
    assert text.startswith("t,q_w,q_x,q_y,q_z,heading_std_deg"), text[:100]
    sid = page.url.rstrip("/").rsplit("/", 1)[-1]  # the report's page: /sessions/<id>
    assert dl.value.suggested_filename == f"session-{sid}-details.csv"
    with page.expect_download() as dl:
        page.locator("[data-export=json]").click()
    assert '"cycles"' in Path(dl.value.path()).read_text(encoding="utf-8")
    with page.expect_download() as dl:
        page.locator("[data-export=recording]").click()
    first = gzip.decompress(Path(dl.value.path()).read_bytes()).splitlines()[0]
    assert json.loads(first)["key"].startswith(f"rehab/{DEVICE}/"), first[:100]
    with page.expect_download() as dl:
        page.locator("[data-export=pdf]").click()
    assert Path(dl.value.path()).read_bytes().startswith(b"%PDF")
    with page.expect_download() as dl:
        page.locator("[data-export=fhir]").click()
    bundle = json.loads(Path(dl.value.path()).read_text(encoding="utf-8"))
    assert (
        bundle["resourceType"] == "Bundle"
        and bundle["entry"][0]["resource"]["identifier"][0]["value"] == PATIENT
    )
    with page.expect_download() as dl:
        page.locator("[data-export=mcap]").click()
    assert Path(dl.value.path()).read_bytes()[:8] == b"\x89MCAP0\r\n"
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
    # Trends of the compensatory-cycle share, the elbow's and the shoulder's range of motion
    # (upper-arm elevation and azimuth), each with its session drawn.
    for plot, colours in (("trend-compensatory", [COMP]), ("trend-elbow", [ELBOW]),
                          ("trend-shoulder", [ELEV, AZIM]), ("trend-isb", [ELEV]),
                          ("trend-sparc", [DISP])):  # fmt: skip
        canvas = page.locator(f"[data-plot={plot}] canvas")
        expect(canvas).to_be_visible(timeout=15_000)
        for colour in colours:
            drawn = colour_pixels(page, f"[data-plot={plot}] canvas", colour)
            assert drawn > 15, (plot, colour, drawn)
    shoulder = page.locator("figure", has=page.locator("[data-plot=trend-shoulder]"))
    expect(shoulder).to_contain_text("Shoulder range of motion")
    expect(shoulder).to_contain_text("elevation")
    expect(shoulder).to_contain_text("azimuth")
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
    expect(page.locator("section[aria-labelledby=compare-title]")).to_contain_text(
        "Comparing needs two finished sessions"
    )
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


@pytest.fixture(scope="module")
def grid(service: Service) -> Iterator[list[SimDevice]]:
    """Four simulated devices; ``BAD_DEVICE`` sends one malformed IMU message early on."""
    from simulator.publish import Outgoing

    sims = [
        SimDevice(service.zenoh, n, GRID_LAYOUT, seed=10 + i, head_s=0, fast_until_s=60, fast=8)
        for i, n in enumerate(GRID)
    ]
    bad = sims[GRID.index(BAD_DEVICE)]
    # 24 s of data = 3 s of sending at 8x: after a worker holds the device (rehab serve's
    # default), so the message is counted by its holder, not lost before the first lease
    k, imu = next((k, o) for k, o in enumerate(bad.outgoing) if o.at >= 24.0 and "/imu" in o.key)
    bad.outgoing.insert(k, Outgoing(imu.at, imu.key, b"{not json"))
    for s in sims:
        s.start()
    try:
        yield sims
    finally:
        for s in sims:
            s.stop()


def test_four_devices_at_20_updates_per_second(
    page: Page, device: SimDevice, grid: list[SimDevice], console: ConsoleLog
) -> None:
    device.stop()  # its session is over: four devices, not five, share the two cores
    assert device.error is None, device.error
    names = GRID
    page.bring_to_front()  # a background tab gets no animation frames, timers at 1/s
    page.goto(f"/grid?devices={','.join(names)}")
    for n in names:
        cell = page.locator(f".grid-cell[data-device={n}]")
        expect(cell.locator(".online--yes")).to_be_visible(timeout=20_000)
    # Calibrated (the first minute is played 8x faster), then real time.
    for n in names:
        cell = page.locator(f".grid-cell[data-device={n}] .indicator")
        expect(cell).not_to_have_attribute("data-state", "waiting", timeout=30_000)
    page.wait_for_timeout(1500)
    assert page.evaluate("document.visibilityState") == "visible"
    before = page.evaluate("structuredClone(window.__rehabLive)")
    t0 = time.monotonic()
    page.wait_for_timeout(5000)
    after = page.evaluate("structuredClone(window.__rehabLive)")
    dt = time.monotonic() - t0
    rates = {n: (after["frames"].get(n, 0) - before["frames"].get(n, 0)) / dt for n in names}
    sent = {n: (after["estimates"].get(n, 0) - before["estimates"].get(n, 0)) / dt for n in names}
    fps = (after["animationFrames"] - before["animationFrames"]) / dt
    print(
        f"dashboard updates/s with four devices: {rates}; estimate messages/s: {sent}; "
        f"animation frames/s: {fps:.1f}"
    )
    shot(page, "grid", full_page=True)
    assert all(r >= 20 for r in rates.values()), rates
    for s in grid:
        assert s.error is None, s.error
    no_console_errors(console)


def test_device_list_online_offline_and_data_quality(
    page: Page, grid: list[SimDevice], console: ConsoleLog
) -> None:
    page.goto("/")
    expect(page.get_by_role("heading", name="Devices", exact=True)).to_be_visible()
    cards = {n: page.locator(f".device-card[data-device={n}]") for n in GRID}
    for n, card in cards.items():
        expect(card.locator(".online")).to_have_text(re.compile("Online"), timeout=10_000)
        badges = card.get_by_role("list", name="Data quality").locator("li")
        if n == BAD_DEVICE:
            expect(badges).to_have_text(["1 rejected"], timeout=10_000)
            expect(badges.first).to_have_attribute(
                "title", re.compile(r"^Rejected messages \(\w+: 1\)$")
            )
        else:
            expect(badges).to_have_text(["Data OK"], timeout=10_000)
        expect(card).to_contain_text("Calibrated")
        expect(card).to_contain_text(re.compile(r"IMU \d+ Hz · robot \d+ Hz"))
    expect(
        page.get_by_role("link", name=re.compile(r"Watch \d+ online devices together"))
    ).to_be_visible()
    shot(page, "devices", full_page=True)

    # Switched off: offline, and no data to vouch for.
    for s in grid:
        s.stop()
    for card in cards.values():
        expect(card.locator(".online")).to_have_text("○Offline", timeout=20_000)
        expect(card.get_by_role("list", name="Data quality").locator("li")).to_have_text(
            ["No data"]
        )
    no_console_errors(console)


def test_nothing_is_fetched_from_another_host(service: Service, console: ConsoleLog) -> None:
    """Everything the pages, the overlay and the embedded 3D view loaded or connected to
    came from this machine's service, on its own port (the 3D view through its proxy path)."""
    service_port = urlsplit(service.url).port
    hosts = {
        urlsplit(u).hostname for u in console.urls if urlsplit(u).scheme not in {"data", "blob"}
    }
    assert hosts == {"127.0.0.1"}, sorted({u for u in console.urls if "127.0.0.1" not in u})
    ports = {urlsplit(u).port for u in console.urls if urlsplit(u).scheme in {"http", "ws"}}
    # the 3D view too: through the service's own port (its authenticated proxy path)
    assert ports == {service_port}, ports
    paths = {urlsplit(u).path for u in console.urls if urlsplit(u).scheme == "ws"}
    assert {"/api/ws/live", "/api/ws/overlay"} <= paths, paths
    assert any(p.startswith("/api/viz/view") for p in paths), paths  # the 3D view was watched
