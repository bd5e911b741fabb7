"""The patient page's two-session comparison with two real sessions: two simulated devices
stream over Zenoh to ``rehab serve`` (see conftest), one session each for one patient, one
with compensation and one without; the figures shown side by side are checked against the
two sessions' report.json; a screenshot is kept. Then a wearable session's report page."""

from __future__ import annotations

import json
import re
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from backend.cli import main
from tests.ui.conftest import ConsoleLog, Service, SimDevice, shot

pytest.importorskip("playwright.sync_api", reason="playwright not installed (dev extra)")
from playwright.sync_api import Browser, Page, expect

PATIENT = "UI-CMP"
# calibration first (the heading converges), then the task; played 8x faster than real time
LAYOUTS = {
    "cmp01": (("rest", 3.0), ("proper", 70.0), ("compensatory", 30.0), ("proper", 15.0)),
    "cmp02": (("rest", 3.0), ("proper", 110.0)),
}


@pytest.fixture(scope="module")
def two_sessions(service: Service) -> Iterator[dict[str, Any]]:
    """Two finished sessions of one patient; their ids (older first) and reports."""
    api = service.api()
    r = api.post("/api/patients", json={"code": PATIENT, "affected_side": "right"})
    assert r.status_code == 201, r.text
    pid = r.json()["id"]
    sims = {
        name: SimDevice(
            service.zenoh,
            name,
            layout,
            seed=20 + i,
            head_s=1.0,
            fast_until_s=sum(d for _, d in layout),
            fast=8.0,
            gated=True,
        )
        for i, (name, layout) in enumerate(LAYOUTS.items())
    }
    ids: list[int] = []
    try:
        for sim in sims.values():
            sim.start()
        for name, sim in sims.items():
            sim.wait_known(service)
            r = api.post("/api/sessions", json={"patient_id": pid, "device": name})
            assert r.status_code == 201, r.text
            ids.append(r.json()["id"])
            sim.go()
            time.sleep(1.5)  # the second starts later: an order on the history's dates
        for sim in sims.values():
            sim.join(120)
            assert not sim.is_alive() and sim.error is None, sim.error
        time.sleep(1.0)  # the last messages reach the pipelines
        for sid in ids:
            r = api.post(f"/api/sessions/{sid}/stop")
            assert r.status_code == 200, r.text
        reports = {sid: api.get(f"/api/sessions/{sid}/report").json()["report"] for sid in ids}
        yield {"patient_id": pid, "ids": ids, "reports": reports}
    finally:
        for sim in sims.values():
            sim.stop()
        api.close()


@pytest.fixture(scope="module")
def page(browser: Browser, service: Service) -> Iterator[Page]:
    ctx = browser.new_context(base_url=service.url, viewport={"width": 1440, "height": 1000})
    ctx.set_default_timeout(15_000)
    p = ctx.new_page()
    p.goto("/")
    p.get_by_label("Username").fill(service.username)
    p.get_by_label("Password").fill(service.password)
    p.keyboard.press("Enter")
    expect(p.get_by_role("heading", name="Devices", exact=True)).to_be_visible()
    try:
        yield p
    finally:
        ctx.close()


def _deg(x: float | None) -> str:
    return "–" if x is None else f"{x:.0f}°"


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{x * 100:.0f} %"


def _num(x: float | None, digits: int) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def _expected(rep: dict[str, Any]) -> dict[str, str]:
    """The comparison's rows as the page should show them, from report.json."""
    s, rom, mq = rep["summary"], rep["anatomical_rom"]["session"], rep["movement_quality"]
    med = mq["session_median"]

    def rng(r: dict[str, Any] | None) -> float | None:
        if not r:
            return None
        if r.get("range") is not None:
            return float(r["range"])
        lo, hi = r.get("p5", r.get("min")), r.get("p95", r.get("max"))
        return None if lo is None or hi is None else hi - lo

    disp = rep["shoulder_displacement_m"]["median"]
    return {
        "Cycles": str(s["cycles"]),
        "Compensatory cycles": _pct(s["compensatory_share"]),
        "Shoulder displacement, median": "–" if disp is None else f"{disp * 100:.1f} cm",
        "Elbow flexion, active range": _deg(rng(rep["elbow_flexion_deg"])),
        "Shoulder elevation (ISB), active range": _deg(rom["shoulder_elevation_deg"]["range"]),
        "Upper-arm elevation, range": _deg(rng(rep["upper_arm_elevation_deg"])),
        "Smoothness (SPARC), median": _num(med["sparc"], 2),
        "Straightness, median": _num(med["straightness_ratio"], 2),
        "Movement units, median": _num(med["movement_units"], 0),
    }


def test_two_sessions_side_by_side(
    page: Page, service: Service, two_sessions: dict[str, Any]
) -> None:
    console = ConsoleLog()
    console.watch(page)
    older, newer = two_sessions["ids"]
    reports = two_sessions["reports"]
    assert reports[older]["summary"]["compensatory_cycles"] > 0  # the sessions differ
    assert reports[newer]["summary"]["compensatory_cycles"] == 0
    page.goto(f"/patients/{two_sessions['patient_id']}")
    section = page.locator("section[aria-labelledby=compare-title]")
    table = section.locator("[data-table=compare]")
    expect(table).to_be_visible()
    # default: A the older, B the newer session, each linked to its report
    head = table.locator("thead th")
    expect(head.nth(1).locator("a")).to_have_attribute("href", f"/sessions/{older}")
    expect(head.nth(2).locator("a")).to_have_attribute("href", f"/sessions/{newer}")

    def shown() -> dict[str, tuple[str, str]]:
        rows = table.locator("tbody tr")
        out = {}
        for i in range(rows.count()):
            row = rows.nth(i)
            cells = row.locator("td").all_inner_texts()
            out[row.locator("th").inner_text().strip()] = (cells[0].strip(), cells[1].strip())
        return out

    want_a, want_b = _expected(reports[older]), _expected(reports[newer])
    got = shown()
    for label, a in want_a.items():
        assert got[label] == (a, want_b[label]), label
    # real figures, not dashes: both sessions were judged and measured
    for label in ("Cycles", "Shoulder elevation (ISB), active range", "Smoothness (SPARC), median"):
        assert "–" not in got[label], (label, got[label])
    assert got["Compensatory cycles"][0] != got["Compensatory cycles"][1]
    section.scroll_into_view_if_needed()
    shot(page, "patient-compare", full_page=True)

    # swapping the two: the columns follow the choice
    section.locator("select[data-compare='Session A']").select_option(str(newer))
    section.locator("select[data-compare='Session B']").select_option(str(older))
    expect(head.nth(1).locator("a")).to_have_attribute("href", f"/sessions/{newer}")
    swapped = shown()
    assert all(swapped[k] == (v[1], v[0]) for k, v in got.items())
    assert re.match(r"^\d+$", swapped["Cycles"][0])
    assert not console.errors, console.errors


def test_a_robot_sessions_report_page_still_loads_its_cycles_and_csvs(
    page: Page, two_sessions: dict[str, Any]
) -> None:
    """The report page asks for the cycles and CSVs once it knows the session is a robot
    one: they are all there."""
    console = ConsoleLog()
    console.watch(page)
    older = two_sessions["ids"][0]
    rep = two_sessions["reports"][older]
    page.goto(f"/sessions/{older}")
    n = rep["summary"]["cycles"]
    expect(page.get_by_label("Summary")).to_contain_text(f"of {n}")
    cycles = page.get_by_role("region", name="Cycles with their verdicts")
    expect(cycles.locator("tbody tr")).to_have_count(n)
    expect(page.locator("[data-plot=report-displacement] canvas")).to_be_visible(timeout=20_000)
    expect(page.locator("[data-plot=report-arm] canvas")).to_be_visible(timeout=20_000)
    expect(page.locator("[data-export]")).to_have_count(7)
    assert not console.errors, console.errors


def test_a_wearable_sessions_report_page(
    page: Page, service: Service, two_sessions: dict[str, Any], tmp_path: Path
) -> None:
    """A wearable session's report (contract §8, what ``rehab analyze`` writes for it) on
    the report page: its key figures, the ISB and the model's angles, the movements' quality
    and wrist paths without verdicts, and no robot-only sections."""
    sim, out = tmp_path / "sim", tmp_path / "out"
    args = ["--move", "reaching", "--duration", "45", "--seed", "3", "--ideal"]
    assert main(["simulate", "--mode", "wearable", *args, "--out", str(sim)]) == 0
    rec = sim / "recording.jsonl.gz"
    assert main(["analyze", str(rec), "--params", str(sim / "params.json"), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    n_moves = len(report["movements"])
    assert n_moves > 0
    api = service.api()
    try:
        r = api.post(
            "/api/sessions", json={"patient_id": two_sessions["patient_id"], "device": "cmp01"}
        )
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
        assert api.post(f"/api/sessions/{sid}/stop").status_code == 200
    finally:
        api.close()
    # what the live wearable side leaves for a finished session: its recording and outputs
    dest = service.data_dir / "recordings"
    shutil.copy(rec, dest / f"{sid}.jsonl.gz")
    shutil.rmtree(dest / str(sid), ignore_errors=True)
    shutil.copytree(out, dest / str(sid))

    console = ConsoleLog()
    console.watch(page)
    page.goto(f"/sessions/{sid}")
    figures = page.locator("[aria-label=Summary][data-mode=wearable] .figure")
    expect(figures).to_have_count(3)
    expect(figures.nth(0)).to_contain_text("Shoulder elevation")
    rng = report["key_figures"][0]["value"]
    expect(figures.nth(0)).to_contain_text(f"{rng:.0f}°")
    rom = page.locator("section[aria-labelledby=rom-title]")
    expect(rom.locator("[data-table=rom] tbody tr")).to_have_count(8)
    expect(rom.locator("[data-table=rom]")).to_contain_text("Shoulder flexion (model)")
    expect(rom.locator("[data-note=frame]")).to_contain_text("shoulder frame S")
    rom.locator("summary").click()
    expect(rom.locator("[data-table=rom-cycles] tbody tr")).to_have_count(n_moves)
    mq = page.locator("section[aria-labelledby=mq-title]")
    expect(mq.locator("[data-table=movement-quality] tbody tr")).to_have_count(n_moves + 1)
    expect(mq.locator("[data-plot=wrist-paths] polyline[data-verdict=none]")).to_have_count(n_moves)
    expect(mq).to_contain_text("no verdict")
    expect(page.locator("section[aria-labelledby=cycles-title]")).to_have_count(0)
    expect(page.locator("section[aria-labelledby=plots-title]")).to_have_count(0)
    expect(page.locator("[data-export]")).to_have_count(5)  # no robot CSVs
    shot(page, "report-wearable", full_page=True)
    with page.expect_download() as dl:
        page.locator("[data-export=pdf]").click()
    assert Path(dl.value.path()).read_bytes().startswith(b"%PDF")
    assert not console.errors, console.errors
