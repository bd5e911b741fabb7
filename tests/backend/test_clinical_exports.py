"""The clinical exports: the PDF report (rendered and rasterised), the FHIR R4 Bundle
(validated with fhir.resources, sent to a local FHIR-like server), the MCAP file (read back
message by message); through ``rehab export`` and through the REST API, audited."""

from __future__ import annotations

import json
import shutil
import subprocess
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from fhir.resources.R4B.bundle import Bundle
from mcap.reader import make_reader
from PIL import Image
from sqlalchemy import update

from backend.analysis import read_estimates
from backend.cli import main
from backend.db.models import Session as SessionRow
from backend.deps import AppState
from backend.exports import ExportMeta, fhir, mcap_file, pdf
from backend.settings import Settings
from protocol import recording
from tests.backend.test_storage import _patient_and_device, audit_log
from tests.conftest import Session

META = ExportMeta(
    session="7",
    device="sim01",
    patient_code="P-0042",
    started_at=datetime(2026, 1, 2, 9, 0, tzinfo=UTC),
    stopped_at=datetime(2026, 1, 2, 9, 30, tzinfo=UTC),
    therapist="anna",
)


@dataclass
class Analysed:
    recording: Path
    out: Path
    report: dict[str, Any]


@pytest.fixture(scope="module")
def analysed(tmp_path_factory: pytest.TempPathFactory, short_session: Session) -> Analysed:
    d = tmp_path_factory.mktemp("exports")
    rec = d / "session.jsonl.gz"
    lines = [*short_session.raw]
    recording.write(rec, lines)
    # one line that is not a message: the MCAP file keeps it on /rejected
    with open(d / "session.jsonl", "w") as fh:
        for k, p in lines[:50]:
            fh.write(json.dumps({"key": k, "payload": p}) + "\n")
        fh.write("not json\n")
    assert main(["analyze", str(rec), "--out", str(d / "out")]) == 0
    return Analysed(rec, d / "out", json.loads((d / "out" / "report.json").read_text()))


# ---- PDF


def _page_one(pdf_bytes: bytes, tmp: Path) -> Image.Image:
    if shutil.which("pdftoppm") is None:
        pytest.skip("pdftoppm missing: install Debian's poppler-utils (./run test does)")
    (tmp / "r.pdf").write_bytes(pdf_bytes)
    subprocess.run(
        ["pdftoppm", "-r", "60", "-f", "1", "-l", "1", "-png", str(tmp / "r.pdf"), str(tmp / "p")],
        check=True,
        timeout=60,
    )
    (png,) = tmp.glob("p*.png")
    return Image.open(png).convert("RGB")


def _pages(pdf_bytes: bytes, tmp: Path) -> int:
    (tmp / "n.pdf").write_bytes(pdf_bytes)
    out = subprocess.run(
        ["pdfinfo", str(tmp / "n.pdf")], check=True, capture_output=True, text=True, timeout=60
    ).stdout
    return int(next(x for x in out.splitlines() if x.startswith("Pages:")).split()[1])


def test_pdf_page_one_is_not_blank(analysed: Analysed, tmp_path: Path) -> None:
    body = pdf.render(analysed.report, META)
    assert body.startswith(b"%PDF")
    img = np.asarray(_page_one(body, tmp_path)).astype(int)
    ink = np.any(img < 200, axis=2).mean()
    assert ink > 0.03, f"page 1 is nearly blank ({ink:.3%} ink)"
    # both verdict colours are drawn (the wrist paths and the bars)
    red = (img[..., 0] > 150) & (img[..., 1] < 90) & (img[..., 2] < 90)
    green = (img[..., 1] > 100) & (img[..., 0] < 90) & (img[..., 2] < 90)
    assert red.sum() > 50 and green.sum() > 50
    assert _pages(body, tmp_path) <= 2
    # a session without cycles still renders a page with the key figures
    empty = pdf.render({"cycles": [], "summary": {"cycles": 0}}, META)
    (tmp_path / "empty").mkdir()
    assert np.any(np.asarray(_page_one(empty, tmp_path / "empty")) < 200)


# ---- FHIR


def test_fhir_bundle_is_valid_r4_with_the_reports_figures(analysed: Analysed) -> None:
    b = fhir.bundle(analysed.report, META)
    parsed = Bundle.model_validate(b)  # raises on any invalid element
    assert parsed.type == "collection"
    resources = [e.resource for e in parsed.entry]
    kinds = [r.__resource_type__ for r in resources]
    assert kinds[:2] == ["Patient", "DiagnosticReport"] and set(kinds[2:]) == {"Observation"}
    patient = resources[0]
    assert patient.name is None and patient.identifier[0].value == "P-0042"  # pseudonymous
    full = {e.fullUrl for e in parsed.entry}
    report = resources[1]
    assert report.subject.reference in full
    assert {r.reference for r in report.result} == full - {
        f"urn:uuid:{patient.id}",
        f"urn:uuid:{report.id}",
    }
    by_code = {o.code.coding[-1].code: o for o in resources[2:]}
    rep = analysed.report
    assert float(by_code["compensatory_cycles_pct"].valueQuantity.value) == pytest.approx(
        100 * rep["summary"]["compensatory_share"]
    )
    elev = rep["anatomical_rom"]["session"]["shoulder_elevation_deg"]
    rom = by_code["rom.shoulder_elevation_deg"]
    assert float(rom.valueQuantity.value) == pytest.approx(elev["range"])
    assert (
        rom.valueQuantity.code == "deg" and rom.valueQuantity.system == "http://unitsofmeasure.org"
    )
    assert {
        c.code.coding[-1].code: float(c.valueQuantity.value) for c in rom.component
    } == pytest.approx(
        {f"rom.shoulder_elevation_deg.{k}": elev[k] for k in ("min", "max", "p5", "p95")}
    )
    sparc = by_code["quality.sparc.median"]
    assert float(sparc.valueQuantity.value) == pytest.approx(
        rep["movement_quality"]["session_median"]["sparc"]
    )
    assert float(by_code["cycles"].valueQuantity.value) == rep["summary"]["cycles"]
    # the same session gives the same Bundle (ids are derived, not random)
    assert fhir.bundle(analysed.report, META) == b


def test_fhir_missing_values_are_marked_absent() -> None:
    b = fhir.bundle(
        {
            "cycles": [],
            "summary": {"cycles": 0},
            "key_figures": [{"key": "sparc_median", "label": "SPARC", "value": None, "unit": "1"}],
        },
        META,
    )
    obs = Bundle.model_validate(b).entry[2].resource
    assert obs.valueQuantity is None and obs.dataAbsentReason is not None


@dataclass
class FhirServer:
    url: str
    received: list[dict[str, Any]] = field(default_factory=list)
    fail: bool = False


@pytest.fixture
def fhir_server() -> Iterator[FhirServer]:
    """A FHIR-like server on loopback: accepts a transaction Bundle at its base URL and
    answers with a transaction-response (or 422 when told to fail)."""
    state = FhirServer(url="")

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
            state.received.append(body)
            if state.fail or body.get("type") != "transaction":
                self.send_response(422)
                self.end_headers()
                self.wfile.write(b'{"resourceType": "OperationOutcome"}')
                return
            answer = {
                "resourceType": "Bundle",
                "type": "transaction-response",
                "entry": [
                    {
                        "response": {
                            "status": "201 Created",
                            "location": f"{e['request']['url']}/{i}",
                        }
                    }
                    for i, e in enumerate(body["entry"])
                ],
            }
            data = json.dumps(answer).encode()
            self.send_response(200)
            self.send_header("Content-Type", "application/fhir+json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def log_message(self, *args: Any) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    state.url = f"http://127.0.0.1:{server.server_address[1]}/fhir"
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield state
    finally:
        server.shutdown()
        server.server_close()


def test_fhir_send_posts_a_transaction(analysed: Analysed, fhir_server: FhirServer) -> None:
    answer = fhir.send(analysed.report, META, fhir_server.url)
    assert answer["type"] == "transaction-response"
    (sent,) = fhir_server.received
    parsed = Bundle.model_validate(sent)
    assert parsed.type == "transaction"
    assert all(e.request.method == "POST" for e in parsed.entry)
    assert parsed.entry[0].request.ifNoneExist == f"identifier={fhir.PATIENT_SYSTEM}|P-0042"
    fhir_server.fail = True
    with pytest.raises(fhir.FhirSendError, match="422"):
        fhir.send(analysed.report, META, fhir_server.url)
    with pytest.raises(fhir.FhirSendError, match="cannot be reached"):
        fhir.send(analysed.report, META, "http://127.0.0.1:9/fhir", timeout_s=2.0)


# ---- MCAP


def _read_mcap(data: bytes) -> list[tuple[str, str, str, int, Any]]:
    import io

    reader = make_reader(io.BytesIO(data))
    out = []
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        assert schema is not None and schema.encoding == "jsonschema"
        json.loads(schema.data)  # every schema is JSON
        assert channel.message_encoding == "json"
        out.append(
            (
                channel.topic,
                schema.name,
                message.sequence,
                message.log_time,
                json.loads(message.data),
            )
        )
    return out


def test_mcap_holds_every_message(analysed: Analysed, short_session: Session) -> None:
    import io

    buf = io.BytesIO()
    est = read_estimates(analysed.out / "estimates.csv")
    n = mcap_file.write(buf, analysed.recording, analysed.report, est, META)
    got = _read_mcap(buf.getvalue())
    assert len(got) == n
    assert [g[2] for g in got] == list(range(n))  # in source order
    raw = short_session.raw
    rec_part, rest = got[: len(raw)], got[len(raw) :]
    for (key, payload), (topic, _, _, log_time, data) in zip(raw, rec_part, strict=True):
        assert topic == key and data == json.loads(json.dumps(payload))
        t = payload["t"][0] if isinstance(payload["t"], list) else payload["t"]
        assert log_time == round(t * 1e9)
    estimates = [g for g in rest if g[0] == "rehab/sim01/estimate"]
    assert len(estimates) == len(est["t"])
    for i in (0, len(estimates) // 2, len(estimates) - 1):
        row = estimates[i][4]
        assert row["t"] == est["t"][i] and row["state"] == (est["state"][i] or None)
        for k in ("elbow_angle_deg", "shoulder_displacement_m"):
            v = est[k][i]
            assert row[k] == (None if np.isnan(v) else v)
    cycles = [g for g in rest if g[0] == "rehab/sim01/cycle"]
    assert [c[4]["start"] for c in cycles] == [c["start"] for c in analysed.report["cycles"]]
    assert all("sparc" in c[4] and c[1] == "rehab.Cycle" for c in cycles)
    assert len(estimates) + len(cycles) == len(rest)


def test_mcap_keeps_a_bad_line(analysed: Analysed) -> None:
    import io

    buf = io.BytesIO()
    path = analysed.recording.with_name("session.jsonl")
    mcap_file.write(buf, path, {"cycles": []}, None, META)
    got = _read_mcap(buf.getvalue())
    assert len(got) == 51
    assert got[-1][0] == "/rejected" and got[-1][4]["line"].startswith("not json")
    assert got[-1][3] == got[-2][3]  # logged at the last good time


# ---- rehab export


def test_cli_export_writes_all_three(analysed: Analysed, tmp_path: Path, capsys) -> None:
    args = ["export", str(analysed.recording), "--analysis", str(analysed.out)]
    out = {k: tmp_path / f"s.{k}" for k in ("pdf", "json", "mcap")}
    assert (
        main(
            [
                *args,
                "--pdf",
                str(out["pdf"]),
                "--fhir",
                str(out["json"]),
                "--mcap",
                str(out["mcap"]),
                "--patient",
                "P-0042",
                "--started",
                "2026-01-02T10:00:00+01:00",
            ]
        )
        == 0
    )
    assert "wrote" in capsys.readouterr().out
    assert out["pdf"].read_bytes().startswith(b"%PDF")
    b = Bundle.model_validate_json(out["json"].read_text())
    assert b.entry[1].resource.effectivePeriod.start.isoformat().startswith("2026-01-02T09:00:00")
    assert len(_read_mcap(out["mcap"].read_bytes())) > len(analysed.report["cycles"])
    assert main([*args]) == 2  # nothing asked
    assert main(["export", str(analysed.recording), "--analysis", str(tmp_path), "--pdf", "x"]) == 2
    with pytest.raises(SystemExit, match="time zone"):
        main([*args, "--pdf", str(out["pdf"]), "--started", "2026-01-02T10:00:00"])


# ---- REST


@pytest.fixture
def settings(tmp_path: Path, db_url: str, fhir_server: FhirServer) -> Settings:
    return Settings(data_dir=tmp_path / "data", database_url=db_url, fhir_url=fhir_server.url)


@pytest.mark.anyio
async def test_rest_exports_are_guarded_and_audited(
    client: httpx.AsyncClient,
    state: AppState,
    admin: dict[str, str],
    analysed: Analysed,
    fhir_server: FhirServer,
) -> None:
    pid = await _patient_and_device(client, state, admin, device="sim01")
    r = await client.post(
        "/api/sessions", json={"patient_id": pid, "device": "sim01"}, headers=admin
    )
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    assert (await client.post(f"/api/sessions/{sid}/fhir/send", headers=admin)).status_code == 409
    assert (await client.post(f"/api/sessions/{sid}/stop", headers=admin)).status_code == 200
    # the simulated session's recording stands in for what the live side recorded (nothing)
    rel = f"recordings/imported-{sid}.jsonl.gz"
    dest = state.settings.data_dir / rel
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(analysed.recording, dest)
    async with state.database.transaction() as db:
        await db.execute(update(SessionRow).where(SessionRow.id == sid).values(recording_path=rel))

    base = f"/api/sessions/{sid}"
    for path in ("report.pdf", "fhir", "recording.mcap"):
        assert (await client.get(f"{base}/{path}")).status_code == 401  # no credentials
    r = await client.get(f"{base}/report.pdf", headers=admin)
    assert r.status_code == 200 and r.headers["content-type"] == "application/pdf"
    assert r.content.startswith(b"%PDF")
    r = await client.get(f"{base}/fhir", headers=admin)
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/fhir+json")
    bundle = Bundle.model_validate(r.json())
    patient = bundle.entry[0].resource
    assert patient.identifier[0].value == "P-sim01" and patient.name is None
    r = await client.get(f"{base}/recording.mcap", headers=admin)
    assert r.status_code == 200
    got = _read_mcap(r.content)
    assert sum(1 for g in got if g[0] == "rehab/sim01/cycle") == len(analysed.report["cycles"])
    r = await client.post(f"{base}/fhir/send", headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["response"]["type"] == "transaction-response"
    assert fhir_server.received[-1]["entry"][0]["resource"]["identifier"][0]["value"] == "P-sim01"
    fhir_server.fail = True
    r = await client.post(f"{base}/fhir/send", headers=admin)
    assert r.status_code == 502 and "422" in r.json()["detail"]
    assert (await client.get("/api/sessions/999/report.pdf", headers=admin)).status_code == 404
    log = await audit_log(state)
    for action in ("export.pdf", "export.fhir", "export.mcap", "export.fhir_send"):
        assert ("admin", action, f"session:{sid}") in log
    assert sum(1 for a in log if a[1] == "export.fhir_send") == 2  # the failed one too


@pytest.mark.anyio
async def test_fhir_send_without_an_endpoint(
    client: httpx.AsyncClient, state: AppState, admin: dict[str, str]
) -> None:
    state.settings.fhir_url = None
    r = await client.post("/api/sessions/1/fhir/send", headers=admin)
    assert r.status_code == 409 and "REHAB_FHIR_URL" in r.json()["detail"]


# ---- standard codes (LOINC, SNOMED CT body sites, UCUM), Foxglove's needs of the MCAP file


def test_fhir_uses_loinc_snomed_and_ucum_where_they_exist(analysed: Analysed) -> None:
    b = Bundle.model_validate(fhir.bundle(analysed.report, META))
    obs = {o.resource.code.coding[-1].code: o.resource for o in b.entry[2:]}
    duration = obs["exercise_duration"]
    loinc = duration.code.coding[0]
    assert (loinc.system, loinc.code, loinc.display) == (
        "http://loinc.org",
        "55411-3",
        "Exercise duration",
    )
    q = duration.valueQuantity
    assert (q.system, q.code) == ("http://unitsofmeasure.org", "min")
    cycles = analysed.report["cycles"]
    assert float(q.value) == pytest.approx(
        sum(c["end"] - c["start"] for c in cycles) / 60, abs=5e-7
    )  # 6 decimals
    cats = {c.coding[0].code for c in duration.category}
    assert cats == {"activity", "PhysicalActivity"}  # HL7's, and the Physical Activity IG's
    sites = {
        "rom.shoulder_elevation_deg": "16982005",
        "rom.shoulder_plane_of_elevation_deg": "16982005",
        "rom.elbow_flexion_deg": "16953009",
        "shoulder_elevation_range_deg": "16982005",
    }
    for code, snomed in sites.items():
        site = obs[code].bodySite
        assert (site.coding[0].system, site.coding[0].code) == ("http://snomed.info/sct", snomed)
        assert site.text.startswith(analysed.report["anatomical_rom"]["side"])
        assert obs[code].method.coding[0].code == "method.robot"
    assert obs["sparc_median"].bodySite is None  # the hand path: no joint
    # the project's code system for everything LOINC has not
    assert all(o.code.coding[-1].system == fhir.CODE_SYSTEM for o in obs.values())
    assert [c for o in obs.values() for c in o.code.coding if c.system == "http://loinc.org"] == [
        loinc
    ]


def _validators() -> Any:
    import jsonschema

    return jsonschema


def test_mcap_meets_what_foxglove_needs(analysed: Analysed) -> None:
    """json messages, jsonschema schemas that are valid JSON Schemas and that every message
    validates against, an indexed file read back in log-time order, and each channel's log
    times in order."""
    import io

    from mcap.reader import make_reader

    jsonschema = _validators()
    buf = io.BytesIO()
    est = read_estimates(analysed.out / "estimates.csv")
    n = mcap_file.write(buf, analysed.recording, analysed.report, est, META)
    reader = make_reader(io.BytesIO(buf.getvalue()))
    summary = reader.get_summary()
    assert summary is not None and summary.chunk_indexes  # indexed: seekable by time
    assert summary.statistics is not None and summary.statistics.message_count == n
    checkers: dict[int, Any] = {}
    for sid, schema in summary.schemas.items():
        assert schema.encoding == "jsonschema"
        doc = json.loads(schema.data)
        jsonschema.Draft202012Validator.check_schema(doc)
        checkers[sid] = jsonschema.Draft202012Validator(doc)
    times = []
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        assert schema is not None and channel.message_encoding == "json"
        checkers[schema.id].validate(json.loads(message.data))
        times.append(message.log_time)
    assert len(times) == n and times == sorted(times)
    last: dict[str, int] = {}  # as written: no channel goes back in time
    for _, channel, message in reader.iter_messages(log_time_order=False):
        assert message.log_time >= last.get(channel.topic, 0), channel.topic
        last[channel.topic] = message.log_time
    # a message that breaks its schema is caught (the check can fail)
    (cycle_schema,) = [s for s in summary.schemas.values() if s.name == "rehab.Cycle"]
    bad = {"start": "soon", "end": 1.0, "outside_fraction": 0.1, "compensatory": None}
    with pytest.raises(jsonschema.ValidationError):
        checkers[cycle_schema.id].validate(bad)


# ---- a wearable session (contract §8): PDF, FHIR and MCAP


@pytest.fixture(scope="module")
def wearable(tmp_path_factory: pytest.TempPathFactory) -> Analysed:
    d = tmp_path_factory.mktemp("wearable-exports")
    sim = d / "sim"
    args = ["--move", "reaching", "--duration", "45", "--seed", "3", "--ideal"]
    assert main(["simulate", "--mode", "wearable", *args, "--out", str(sim)]) == 0
    rec = sim / "recording.jsonl.gz"
    assert (
        main(["analyze", str(rec), "--params", str(sim / "params.json"), "--out", str(d / "out")])
        == 0
    )
    return Analysed(rec, d / "out", json.loads((d / "out" / "report.json").read_text()))


def test_wearable_pdf_and_fhir(wearable: Analysed, tmp_path: Path) -> None:
    rep = wearable.report
    assert rep["movements"], "the simulated reaching gives movements"
    body = pdf.render(rep, META)
    img = np.asarray(_page_one(body, tmp_path)).astype(int)
    assert np.any(img < 200, axis=2).mean() > 0.03
    blue = (img[..., 2] > 130) & (img[..., 0] < 80) & (img[..., 1] < 140)  # paths, no verdict
    assert blue.sum() > 50
    assert _pages(body, tmp_path) <= 2
    b = Bundle.model_validate(fhir.bundle(rep, META))
    report = b.entry[1].resource
    assert "Wearable" in report.code.text
    obs = {o.resource.code.coding[-1].code: o.resource for o in b.entry[2:]}
    assert float(obs["movements"].valueQuantity.value) == len(rep["movements"])
    assert "cycles" not in obs and "compensatory_cycles_pct" not in obs
    for name in ("shoulder_elevation_deg", "elbow_flexion_deg", "shoulder_flexion_deg"):
        o = obs[f"rom.{name}"]
        stats = rep["anatomical_rom"]["session"][name]
        assert float(o.valueQuantity.value) == pytest.approx(stats["range"])
        assert o.method.coding[0].code == "method.wearable"
    assert obs["rom.elbow_flexion_deg"].bodySite.coding[0].code == "16953009"
    assert float(obs["elbow_flexion_range_deg"].valueQuantity.value) == pytest.approx(
        rep["anatomical_rom"]["session"]["elbow_flexion_deg"]["range"]
    )
    minutes = sum(m["end"] - m["start"] for m in rep["movements"]) / 60
    # FHIR quantities carry 6 decimals (fhir._quantity)
    assert float(obs["exercise_duration"].valueQuantity.value) == pytest.approx(minutes, abs=5e-7)


def test_wearable_mcap_holds_joints_and_movements(wearable: Analysed, tmp_path: Path) -> None:
    from backend.analysis_wearable import read_joints

    jsonschema = _validators()
    path = tmp_path / "w.mcap"
    args = ["export", str(wearable.recording), "--analysis", str(wearable.out)]
    assert main([*args, "--mcap", str(path)]) == 0
    got = _read_mcap(path.read_bytes())
    joints = read_joints(wearable.out / "joints.csv")
    rows = [g for g in got if g[0] == "rehab/wear01/joints"]
    assert len(rows) == len(joints["t"])
    for i in (0, len(rows) // 2, len(rows) - 1):
        for k, col in joints.items():
            assert rows[i][4][k] == (None if np.isnan(col[i]) else col[i])
    moves = [g for g in got if g[0] == "rehab/wear01/movement"]
    assert [m[4]["start"] for m in moves] == [m["start"] for m in wearable.report["movements"]]
    assert all(m[4]["sparc"] is not None for m in moves)
    from mcap.reader import make_reader

    reader = make_reader(path.open("rb"))
    for schema, _, message in reader.iter_messages():
        assert schema is not None
        jsonschema.validate(json.loads(message.data), json.loads(schema.data))
    assert {g[0] for g in got} >= {"rehab/wear01/imu/upperarm", "rehab/wear01/imu/forearm"}


def test_wearable_session_summary_feeds_the_history(wearable: Analysed) -> None:
    """The sessions table's summary of a wearable report: the same ISB and elbow keys as a
    robot session's, so the patient's trends show both modes side by side."""
    from backend.live.worker import session_summary

    s = session_summary(wearable.report)
    rom = s["anatomical_rom_deg"]
    assert (
        rom["shoulder_elevation_deg"]
        == (wearable.report["anatomical_rom"]["session"]["shoulder_elevation_deg"])
    )
    assert rom["elbow_flexion_deg"]["range"] > 0
    assert s["movement_quality_median"]["sparc"] is not None
    assert s["movements"] == len(wearable.report["movements"])


MCAP_CHECK = Path(__file__).resolve().parents[2] / "tools" / "mcap-check"


def test_mcap_opens_with_foxgloves_reader(analysed: Analysed, tmp_path: Path) -> None:
    """@mcap/core (Foxglove's MCAP library) reads every message back, indexed and
    streamed, CRCs checked, in log-time order, each one JSON with a jsonschema schema."""
    node = shutil.which("node")
    if node is None or not (MCAP_CHECK / "node_modules" / "@mcap" / "core").is_dir():
        pytest.skip("@mcap/core not installed: ./run test installs it (tools/mcap-check)")
    path = tmp_path / "s.mcap"
    est = read_estimates(analysed.out / "estimates.csv")
    n = mcap_file.write(path, analysed.recording, analysed.report, est, META)
    out = subprocess.run(
        [node, str(MCAP_CHECK / "check.mjs"), str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    got = json.loads(out)
    assert got["messages"] == got["streamed"] == got["statistics"] == n
    assert got["ordered"]
    mine = _read_mcap(path.read_bytes())
    topics: dict[str, int] = {}
    for topic, *_ in mine:
        topics[topic] = topics.get(topic, 0) + 1
    assert got["topics"] == topics
    assert set(got["schemas"]) == {s for _, s, *_ in mine}


def test_a_wearable_sessions_outputs_are_regenerated_as_wearable(
    wearable: Analysed, tmp_path: Path
) -> None:
    """A wearable session the service did not stop (no report.json): its outputs are made
    again by the wearable analysis, not the robot pipeline."""
    from backend.live import files

    rec = tmp_path / "recordings" / "5.jsonl.gz"
    rec.parent.mkdir()
    shutil.copy(wearable.recording, rec)
    params = json.loads((wearable.recording.parent / "params.json").read_text())
    report = files.regenerate(rec, params, "wear01")
    assert report["mode"] == "wearable"
    assert report["anatomical_rom"]["session"] == wearable.report["anatomical_rom"]["session"]
    assert (files.outputs_dir(rec) / "joints.csv").is_file()
