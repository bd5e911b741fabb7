"""A session report as a FHIR R4 Bundle: a DiagnosticReport and its Observations (the key
figures, the range of motion per angle, the movement quality's session medians), about a
pseudonymous Patient (an identifier holding the clinic's patient code, nothing else).

Codes. The measures are the project's own: ISB shoulder angles in the robot frame, SPARC,
compensatory cycles... LOINC's range-of-motion codes name goniometric motions (flexion,
abduction, external rotation of a joint), which these are not, so every Observation is coded
in the project's code system :data:`CODE_SYSTEM`, with UCUM units; categories come from HL7's
observation-category and v2-0074 tables. A code gets a LOINC coding beside its own in
:data:`LOINC` where one means exactly the same measurement.

``bundle(..., kind="collection")`` is the file export; ``kind="transaction"`` is what
:func:`send` posts to a FHIR server's base URL (the Patient by conditional create on its
identifier, so sessions of one patient share one Patient there).
"""

from __future__ import annotations

import json
import urllib.error
import urllib.request
import uuid
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any, Literal

from backend.exports import ExportMeta

CODE_SYSTEM = "urn:rehab-tracking:fhir:code"
PATIENT_SYSTEM = "urn:rehab-tracking:patient-code"
UCUM = "http://unitsofmeasure.org"
_NS = uuid.UUID("5d3c7b1e-8a43-4f6e-9a59-2f1f4d1c0e22")  # the project's uuid5 namespace
_OBS_CATEGORY = "http://terminology.hl7.org/CodeSystem/observation-category"
_V2_0074 = "http://terminology.hl7.org/CodeSystem/v2-0074"

# a measure's LOINC coding, only where LOINC has exactly this measurement
LOINC: dict[str, tuple[str, str]] = {}

_UNITS = {"deg": "deg", "%": "%", "1": "1", "m": "m", "s": "s", "m/s": "m/s"}
_ANGLE_NAMES = {
    "shoulder_plane_of_elevation_deg": "Shoulder plane of elevation (ISB)",
    "shoulder_elevation_deg": "Shoulder elevation (ISB)",
    "shoulder_axial_rotation_deg": "Shoulder axial rotation (ISB)",
    "elbow_flexion_deg": "Elbow flexion",
}
QUALITY_NAMES: dict[str, tuple[str, str]] = {  # field: (display, unit)
    "movement_time_s": ("Movement time per cycle", "s"),
    "path_length_m": ("Hand-path length per cycle", "m"),
    "straightness_ratio": ("Straightness ratio", "1"),
    "mean_speed_m_s": ("Mean hand speed", "m/s"),
    "peak_speed_m_s": ("Peak hand speed", "m/s"),
    "movement_units": ("Movement units per cycle", "1"),
    "sparc": ("Smoothness, spectral arc length (SPARC)", "1"),
    "ldlj": ("Smoothness, log dimensionless jerk", "1"),
}
_STATS = ("min", "max", "p5", "p95")

Kind = Literal["collection", "transaction"]


def _id(meta: ExportMeta, name: str) -> str:
    return str(uuid.uuid5(_NS, f"{meta.device}/{meta.session}/{name}"))


def _code(code: str, display: str) -> dict[str, Any]:
    codings = [{"system": CODE_SYSTEM, "code": code, "display": display}]
    if code in LOINC:
        loinc, text = LOINC[code]
        codings.insert(0, {"system": "http://loinc.org", "code": loinc, "display": text})
    return {"coding": codings, "text": display}


def _quantity(value: float | None, unit: str) -> dict[str, Any] | None:
    if value is None:
        return None
    u = _UNITS.get(unit, unit)
    return {"value": round(float(value), 6), "unit": unit, "system": UCUM, "code": u}


def _time(t: datetime | None) -> str | None:
    return t.astimezone(UTC).isoformat() if t is not None else None


def _observation(
    meta: ExportMeta,
    patient_ref: str,
    code: str,
    display: str,
    value: float | None,
    unit: str,
    category: str,
    components: Mapping[str, float | None] | None = None,
    note: str | None = None,
) -> dict[str, Any]:
    obs: dict[str, Any] = {
        "resourceType": "Observation",
        "id": _id(meta, code),
        "status": "preliminary" if meta.provisional else "final",
        "category": [{"coding": [{"system": _OBS_CATEGORY, "code": category}]}],
        "code": _code(code, display),
        "subject": {"reference": patient_ref},
    }
    period = _period(meta)
    if period:
        obs["effectivePeriod"] = period
    q = _quantity(value, unit)
    if q is not None:
        obs["valueQuantity"] = q
    else:
        obs["dataAbsentReason"] = {
            "coding": [
                {
                    "system": "http://terminology.hl7.org/CodeSystem/data-absent-reason",
                    "code": "not-performed",
                }
            ]
        }
    if components:
        obs["component"] = [
            {
                "code": _code(f"{code}.{k}", f"{display}, {k}"),
                **(
                    {"valueQuantity": _quantity(v, unit)}
                    if v is not None
                    else {
                        "dataAbsentReason": {
                            "coding": [
                                {
                                    "system": "http://terminology.hl7.org/CodeSystem/"
                                    "data-absent-reason",
                                    "code": "not-performed",
                                }
                            ]
                        }
                    }
                ),
            }
            for k, v in components.items()
        ]
    if note:
        obs["note"] = [{"text": note}]
    return obs


def _period(meta: ExportMeta) -> dict[str, str]:
    out = {}
    if meta.started_at is not None:
        out["start"] = _time(meta.started_at) or ""
    if meta.stopped_at is not None:
        out["end"] = _time(meta.stopped_at) or ""
    return out


def observations(
    report: Mapping[str, Any], meta: ExportMeta, patient_ref: str
) -> list[dict[str, Any]]:
    """The Observations of one report: key figures, ROM per angle (value: the active range
    p5–p95, components: min, max, p5, p95), movement quality's session medians, and the
    counts of cycles."""
    out = []
    for f in report.get("key_figures", []):
        out.append(
            _observation(
                meta,
                patient_ref,
                f["key"],
                f["label"],
                f["value"],
                f["unit"],
                "exam",
                note=f.get("detail"),
            )
        )
    rom = report.get("anatomical_rom", {})
    for name, stats in rom.get("session", {}).items():
        display = _ANGLE_NAMES.get(name, name)
        out.append(
            _observation(
                meta,
                patient_ref,
                f"rom.{name}",
                f"{display}, active range of motion (p5-p95)",
                stats.get("range"),
                "deg",
                "exam",
                components={k: stats.get(k) for k in _STATS},
                note=rom.get("note") if name.startswith("shoulder") else None,
            )
        )
    quality = report.get("movement_quality", {})
    for name, median in quality.get("session_median", {}).items():
        display, unit = QUALITY_NAMES.get(name, (name, "1"))
        out.append(
            _observation(
                meta,
                patient_ref,
                f"quality.{name}.median",
                f"{display}, session median",
                median,
                unit,
                "activity",
            )
        )
    summary = report.get("summary", {})
    out.append(
        _observation(
            meta,
            patient_ref,
            "cycles",
            "Task cycles judged",
            summary.get("cycles"),
            "1",
            "activity",
        )
    )
    return out


def _conclusion(report: Mapping[str, Any]) -> str:
    parts = []
    for f in report.get("key_figures", []):
        v = f["value"]
        shown = "n/a" if v is None else f"{v:.1f} {f['unit']}".replace(" 1", "")
        parts.append(f"{f['label']}: {shown}" + (f" ({f['detail']})" if f.get("detail") else ""))
    return "; ".join(parts) + "."


def bundle(
    report: Mapping[str, Any],
    meta: ExportMeta,
    kind: Kind = "collection",
    now: datetime | None = None,
) -> dict[str, Any]:
    """The Bundle (a JSON object) of one session's report; ``now`` stamps it (default: the
    session's end, else the current time)."""
    stamp = _time(now or meta.stopped_at or datetime.now(UTC))
    code = meta.patient_code or "unknown"
    patient = {
        "resourceType": "Patient",
        "id": str(uuid.uuid5(_NS, f"patient/{code}")),
        "identifier": [{"system": PATIENT_SYSTEM, "value": code}],
    }
    patient_ref = f"urn:uuid:{patient['id']}"
    obs = observations(report, meta, patient_ref)
    diag: dict[str, Any] = {
        "resourceType": "DiagnosticReport",
        "id": _id(meta, "report"),
        "identifier": [{"system": f"{CODE_SYSTEM}:session", "value": meta.session}],
        "status": "preliminary" if meta.provisional else "final",
        "category": [
            {"coding": [{"system": _V2_0074, "code": "PT", "display": "Physical Therapy"}]}
        ],
        "code": _code("session-report", "Robot-assisted upper-limb rehabilitation session report"),
        "subject": {"reference": patient_ref},
        "issued": stamp,
        "result": [{"reference": f"urn:uuid:{o['id']}"} for o in obs],
        "conclusion": _conclusion(report),
    }
    if _period(meta):
        diag["effectivePeriod"] = _period(meta)
    entries = []
    for res in (patient, diag, *obs):
        entry: dict[str, Any] = {"fullUrl": f"urn:uuid:{res['id']}", "resource": res}
        if kind == "transaction":
            entry["request"] = {"method": "POST", "url": res["resourceType"]}
            if res is patient:
                entry["request"]["ifNoneExist"] = f"identifier={PATIENT_SYSTEM}|{code}"
        entries.append(entry)
    return {
        "resourceType": "Bundle",
        "id": _id(meta, f"bundle-{kind}"),
        "type": kind,
        "timestamp": stamp,
        "entry": entries,
    }


class FhirSendError(Exception):
    """The FHIR server could not be reached or refused the Bundle."""


def send(
    report: Mapping[str, Any], meta: ExportMeta, base_url: str, timeout_s: float = 10.0
) -> dict[str, Any]:
    """POST the transaction Bundle to a FHIR server's base URL; its response Bundle back.
    Blocking (urllib): call it in a worker thread from async code."""
    body = json.dumps(bundle(report, meta, "transaction")).encode()
    req = urllib.request.Request(
        base_url,
        data=body,
        method="POST",
        headers={"Content-Type": "application/fhir+json", "Accept": "application/fhir+json"},
    )
    try:
        with urllib.request.urlopen(req, timeout=timeout_s) as resp:
            text = resp.read().decode("utf-8", "replace")
    except urllib.error.HTTPError as exc:
        detail = exc.read().decode("utf-8", "replace")[:300]
        raise FhirSendError(f"the FHIR server answered {exc.code}: {detail}") from None
    except (urllib.error.URLError, OSError) as exc:
        raise FhirSendError(f"the FHIR server cannot be reached: {exc}") from None
    try:
        answer: dict[str, Any] = json.loads(text) if text.strip() else {}
    except ValueError:
        raise FhirSendError("the FHIR server's answer is not JSON") from None
    return answer
