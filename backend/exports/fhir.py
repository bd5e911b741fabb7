"""A session report as a FHIR R4 Bundle: a DiagnosticReport and its Observations (the key
figures, the range of motion per angle, the movement quality's session medians, the exercise
duration), about a pseudonymous Patient (an identifier holding the clinic's patient code,
nothing else). Robot-mode and wearable-mode reports alike (``report["mode"]``).

Codes (docs/clinical.md lists each mapping and its source):

- **LOINC where it has the measurement:** the exercise duration, LOINC 55411-3 "Exercise
  duration" in UCUM ``min``, as the HL7 Physical Activity IG codes it (with its
  ``PhysicalActivity`` category beside HL7's ``activity``). LOINC's range-of-motion codes
  (e.g. 41387-2, shoulder external rotation AROM) name a goniometric end-of-range test, which
  the active range during an exercise (p5-p95 of an angle's samples) is not; the ISB Euler
  angles, SPARC, compensatory cycles and the rest have none: those are coded in the project's
  code system :data:`CODE_SYSTEM` (:data:`LOINC` holds the LOINC codings).
- **bodySite:** SNOMED CT body structures (:data:`BODY_SITES`), the side in its text.
- **method:** how the angles were measured, in the project's code system (:data:`METHODS`).
- **Units:** UCUM. **Categories:** HL7 observation-category (``exam``, ``activity``);
  the report's HL7 v2-0074 ``PT``.

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

LOINC_SYSTEM = "http://loinc.org"
SNOMED = "http://snomed.info/sct"
PA_CATEGORY_SYSTEM = "http://hl7.org/fhir/us/physical-activity/CodeSystem/pa-temporary-codes"
# a measure's LOINC coding, only where LOINC has exactly this measurement
LOINC: dict[str, tuple[str, str]] = {
    "exercise_duration": ("55411-3", "Exercise duration"),  # HL7 Physical Activity IG
}
# SNOMED CT body structures of the angles (docs/clinical.md: sources)
BODY_SITES: dict[str, tuple[str, str]] = {
    "shoulder": ("16982005", "Shoulder region structure"),
    "elbow": ("16953009", "Elbow joint structure"),
}
METHODS: dict[str, str] = {
    "robot": "Upper-arm IMU fused with the end-effector robot's elbow position, without "
    "magnetometer; ISB shoulder angles relative to the robot frame standing in for the trunk",
    "wearable": "Two IMUs (upper arm, forearm) and an optional camera, DH-model Kalman filter "
    "(Alizadegan & Behzadipour 2016); angles relative to the shoulder frame S fixed at the "
    "start's rest pose",
}

_UNITS = {"deg": "deg", "%": "%", "1": "1", "m": "m", "s": "s", "m/s": "m/s", "min": "min"}
_ANGLE_NAMES = {
    "shoulder_plane_of_elevation_deg": "Shoulder plane of elevation (ISB)",
    "shoulder_elevation_deg": "Shoulder elevation (ISB)",
    "shoulder_axial_rotation_deg": "Shoulder axial rotation (ISB)",
    "elbow_flexion_deg": "Elbow flexion",
    "shoulder_flexion_deg": "Shoulder flexion (wearable model)",
    "shoulder_abduction_deg": "Shoulder abduction (wearable model)",
    "shoulder_rotation_deg": "Shoulder internal rotation (wearable model)",
    "forearm_pronation_deg": "Forearm pronation (wearable model)",
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
        codings.insert(0, {"system": LOINC_SYSTEM, "code": loinc, "display": text})
    return {"coding": codings, "text": display}


def _joint(name: str) -> str | None:
    """The joint of an angle or key figure (a :data:`BODY_SITES` key), if any."""
    if "shoulder" in name:
        return "shoulder"
    if "elbow" in name:
        return "elbow"
    return None


def _body_site(joint: str | None, side: str | None) -> dict[str, Any] | None:
    if joint is None:
        return None
    code, display = BODY_SITES[joint]
    text = f"{side} {joint}" if side in ("left", "right") else joint
    return {"coding": [{"system": SNOMED, "code": code, "display": display}], "text": text}


def _method(mode: str) -> dict[str, Any]:
    return {
        "coding": [{"system": CODE_SYSTEM, "code": f"method.{mode}", "display": METHODS[mode]}],
        "text": METHODS[mode],
    }


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
    body_site: dict[str, Any] | None = None,
    method: dict[str, Any] | None = None,
    extra_category: dict[str, Any] | None = None,
) -> dict[str, Any]:
    obs: dict[str, Any] = {
        "resourceType": "Observation",
        "id": _id(meta, code),
        "status": "preliminary" if meta.provisional else "final",
        "category": [{"coding": [{"system": _OBS_CATEGORY, "code": category}]}],
        "code": _code(code, display),
        "subject": {"reference": patient_ref},
    }
    if extra_category is not None:
        obs["category"].append(extra_category)
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
    if body_site is not None:
        obs["bodySite"] = body_site
    if method is not None:
        obs["method"] = method
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
    p5–p95, components: min, max, p5, p95), movement quality's session medians, the count of
    cycles (robot) or movements (wearable) and the exercise duration."""
    out = []
    mode = "wearable" if report.get("mode") == "wearable" else "robot"
    method = _method(mode)
    rom = report.get("anatomical_rom", {})
    side = rom.get("side") or report.get("params", {}).get("side")
    for f in report.get("key_figures", []):
        joint = _joint(f["key"])
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
                body_site=_body_site(joint, side),
                method=method if joint else None,
            )
        )
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
                body_site=_body_site(_joint(name), side),
                method=method,
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
    if mode == "wearable":
        count = ("movements", "Movements found", summary.get("movements"))
    else:
        count = ("cycles", "Task cycles judged", summary.get("cycles"))
    out.append(_observation(meta, patient_ref, *count, "1", "activity"))
    out.append(
        _observation(
            meta,
            patient_ref,
            "exercise_duration",
            "Exercise duration: time in task cycles or movements",
            _exercise_min(report),
            "min",
            "activity",
            extra_category={
                "coding": [
                    {
                        "system": PA_CATEGORY_SYSTEM,
                        "code": "PhysicalActivity",
                        "display": "Physical Activity",
                    }
                ]
            },
        )
    )
    return out


def _exercise_min(report: Mapping[str, Any]) -> float | None:
    """Minutes spent in the session's task cycles (robot) or movements (wearable)."""
    spans = report.get("movements") if report.get("mode") == "wearable" else report.get("cycles")
    if not spans:
        return None
    return sum(float(c["end"]) - float(c["start"]) for c in spans) / 60.0


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
        "code": _code(
            "session-report",
            "Wearable-sensor upper-limb rehabilitation session report"
            if report.get("mode") == "wearable"
            else "Robot-assisted upper-limb rehabilitation session report",
        ),
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
