"""The report's clinical sections: range of motion in anatomical terms, movement quality per
cycle, and the session's key figures.

Computed from what the analysis accumulates (the estimate rows' columns, the cycles), so that
``rehab analyze`` and the live service write the same sections. Added to ``report.json``
beside the contract's ``cycles`` (contract §6 requires only those).

- ``anatomical_rom``: ISB shoulder angles (:mod:`estimators.anatomy`) from the upper arm's
  orientation in the robot frame, which stands in for the trunk, and the elbow flexion; per
  session and per cycle, over the rows with a converged heading. The statistics take any
  named angle columns (:func:`rom_section`), so the wearable mode's joint angles fit the same
  section.
- ``movement_quality``: :mod:`estimators.movement_quality` on the wrist cuff's path of each
  judged cycle, the session's medians, and the path seen from above (decimated) for plots.
- ``key_figures``: the three outcome variables a report leads with.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators import anatomy
from estimators import movement_quality as mq
from estimators.cycles import Boundary, CycleParams, CycleSegmenter, path_and_reach

# the estimate rows' columns the sections need beyond the analysis' own statistics
COLUMNS = ("q_ra", "wrist")

FRAME_NOTE = (
    "Shoulder angles are relative to the robot frame, which stands in for the trunk (no trunk "
    "sensor): the patient is assumed to face the robot's +y axis, and trunk lean or rotation "
    "appears as shoulder motion."
)
ISB_NOTE = (
    "ISB humerus angles (Wu et al. 2005), Y-X-Y sequence: plane of elevation (0 = abduction, "
    "90 = forward flexion), elevation (0 = arm hanging), axial rotation (positive = internal; "
    "ISB's gamma, undefined below {min_elev:g} deg of elevation)."
)
QUALITY_NOTE = (
    "From the robot's wrist cuff per cycle. Straightness: the hand path over the two straight "
    "lines start -> farthest point -> end (1 = straight out and back). SPARC (Balasubramanian "
    "et al. 2015; fc 10 Hz, amplitude threshold 0.05, zero padding 4) and log dimensionless "
    "jerk of the speed profile: closer to zero is smoother."
)
ELBOW = "elbow_flexion_deg"
PATH_POINTS = 40  # per cycle in the report: enough for a plot from above


Cache = dict[tuple[str, float, float], dict[str, Any]]


def rom_section(
    t: NDArray[np.float64],
    angles: Mapping[str, NDArray[np.float64]],
    cycles: Sequence[Mapping[str, Any]],
    valid: NDArray[np.bool_] | None = None,
    cache: Cache | None = None,
) -> dict[str, Any]:
    """Session and per-cycle ROM statistics of every named angle column (°) over the rows
    where ``valid`` holds; ``t`` (N,) s increasing. ``cache``: per-cycle results kept from an
    earlier call with the same rows (a completed cycle's rows do not change)."""
    mask = np.ones(len(t), dtype=bool) if valid is None else valid
    per_cycle = []
    for c in cycles:
        key = ("rom", c["start"], c["end"])
        row = cache.get(key) if cache is not None else None
        if row is None:
            i0, i1 = np.searchsorted(t, [c["start"], c["end"]], side="left")
            sub = {k: np.asarray(a)[i0:i1] for k, a in angles.items()}
            row = {
                "start": c["start"],
                "end": c["end"],
                "angles": anatomy.rom_table(sub, mask[i0:i1]),
            }
            if cache is not None:
                cache[key] = row
        per_cycle.append(row)
    return {"session": anatomy.rom_table(angles, mask), "cycles": per_cycle}


def quality_section(
    t: NDArray[np.float64],
    wrist: NDArray[np.float64],
    cycles: Sequence[Mapping[str, Any]],
    params: mq.QualityParams = mq.DEFAULT_PARAMS,
    cache: Cache | None = None,
) -> dict[str, Any]:
    """Movement quality of each cycle's wrist path (``wrist`` (N, 3) m at ``t`` (N,) s),
    with the session medians and each path from above (x, y; m, ≤ ``PATH_POINTS`` points).
    ``cache`` as for :func:`rom_section`."""
    rows = []
    for c in cycles:
        key = ("quality", c["start"], c["end"])
        if cache is not None and key in cache:
            rows.append(cache[key])
            continue
        i0, i1 = np.searchsorted(t, [c["start"], c["end"]], side="right")
        i0 = max(int(i0) - 1, 0)  # the sample at the start belongs to the cycle
        tc, pc = t[i0:i1], wrist[i0:i1]
        m = mq.measure(tc, pc, params)
        step = max(1, math.ceil(len(pc) / PATH_POINTS))
        xy = pc[::step, :2]
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        rows.append(
            {
                "start": c["start"],
                "end": c["end"],
                "compensatory": c.get("compensatory"),
                **{k: _num(v) for k, v in m.items()},
                "path_xy": np.round(xy, 4).tolist(),
            }
        )
        if cache is not None:
            cache[key] = rows[-1]
    medians = {}
    for k in mq.QUALITY_FIELDS:
        vals = np.array([r[k] for r in rows if r[k] is not None], dtype=np.float64)
        medians[k] = float(np.median(vals)) if len(vals) else None
    return {
        "source": "wrist cuff",
        "note": QUALITY_NOTE,
        "params": dataclasses.asdict(params),
        "cycles": rows,
        "session_median": medians,
    }


def key_figures(
    cycles: Sequence[Mapping[str, Any]], rom: Mapping[str, Any], quality: Mapping[str, Any]
) -> list[dict[str, Any]]:
    """The report's lead: share of compensatory cycles, the shoulder's active elevation range,
    the median smoothness (SPARC)."""
    judged = [c for c in cycles if c.get("compensatory") is not None]
    n_comp = sum(1 for c in judged if c["compensatory"])
    elev = rom["session"].get("shoulder_elevation_deg", {})
    return [
        {
            "key": "compensatory_cycles_pct",
            "label": "Compensatory cycles",
            "value": 100.0 * n_comp / len(judged) if judged else None,
            "unit": "%",
            "detail": f"{n_comp} of {len(judged)} cycles",
        },
        {
            "key": "shoulder_elevation_range_deg",
            "label": "Shoulder elevation, active range (p5-p95)",
            "value": elev.get("range"),
            "unit": "deg",
            "detail": _span(elev),
        },
        {
            "key": "sparc_median",
            "label": "Smoothness (SPARC, median)",
            "value": quality["session_median"].get("sparc"),
            "unit": "1",
            "detail": "closer to 0 is smoother",
        },
    ]


def sections(
    st: Mapping[str, NDArray[Any]],
    cycles: Sequence[Mapping[str, Any]],
    params: Mapping[str, Any],
    cache: Cache | None = None,
) -> dict[str, Any]:
    """The report's clinical sections from the analysis' accumulated row columns ``st``
    (``t``, ``heading_converged``, ``elbow_angle_deg`` and :data:`COLUMNS`) and its judged
    cycles. ``params``: the session's parameters (``side`` if given, else right).
    ``cache``: a dict kept by the caller between calls over the same growing rows (the live
    service asks for reports mid-session: each cycle is measured once)."""
    n = len(st.get("t", ()))
    t = np.asarray(st["t"], dtype=np.float64) if n else np.zeros(0)
    q = np.asarray(st["q_ra"], dtype=np.float64).reshape(-1, 4) if n else np.zeros((0, 4))
    wrist = np.asarray(st["wrist"], dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
    conv = np.asarray(st["heading_converged"], dtype=bool) if n else np.zeros(0, dtype=bool)
    side: anatomy.Side = "left" if params.get("side") == "left" else "right"
    ap = anatomy.AnatomyParams(side=side)
    angles = anatomy.shoulder_angles(q, ap)
    angles[ELBOW] = np.asarray(st["elbow_angle_deg"], dtype=np.float64) if n else np.zeros(0)
    rom = {
        "reference_frame": "robot",
        "note": FRAME_NOTE,
        "convention": ISB_NOTE.format(min_elev=ap.min_elevation_deg),
        "side": side,
        **rom_section(t, angles, cycles, conv, cache),
    }
    quality = quality_section(t, wrist, cycles, cache=cache)
    return {
        "anatomical_rom": rom,
        "movement_quality": quality,
        "key_figures": key_figures(cycles, rom, quality),
    }


WEARABLE_ANGLES = (
    "shoulder_flexion_deg",
    "shoulder_abduction_deg",
    "shoulder_rotation_deg",
    ELBOW,
    "forearm_pronation_deg",
)  # contract §8's joint angles
WEARABLE_FRAME_NOTE = (
    "Wearable mode (two IMUs, DH model, contract §8): shoulder angles are relative to the "
    "shoulder frame S, fixed at the start's rest pose (no trunk sensor): trunk lean or "
    "rotation after the start appears as shoulder motion. The ISB angles are computed from the "
    "model's joint angles, so they compare with the robot mode's; the model's own angles "
    "(flexion, abduction, rotation, pronation) are listed beside them."
)
WEARABLE_QUALITY_NOTE = (
    "From the wrist position of the wearable model (forearm IMU and the DH chain, in S), not "
    "from a measured end effector, per movement; path_xy seen from above as (right, forward). "
    + QUALITY_NOTE.split(". ", 1)[1]
)


def wearable_movements(
    t: NDArray[np.float64],
    wrist: NDArray[np.float64],
    event_times: Sequence[float] = (),
    params: CycleParams | None = None,
) -> list[dict[str, Any]]:
    """Movements (``{"start", "end"}``, s) of a wearable session from its wrist path
    (``wrist`` (N, 3) m in S, NaN rows skipped; ``t`` (N,) s increasing): the contract's
    ``cycle_start`` events when there are any, else :class:`estimators.cycles.CycleSegmenter`
    on the path seen from above (S's x and y: horizontal, like the robot frame's) with both the
    closed-path and the reaching detectors, keeping the one that finds more movements (the
    wearable mode has no game telling the task). ``params``: the segmenter's parameters
    (``mode`` is overridden)."""
    base = params if params is not None else CycleParams()
    ok = np.all(np.isfinite(wrist), axis=1) if len(wrist) else np.zeros(0, dtype=bool)
    tt, ww = np.asarray(t, dtype=np.float64)[ok], np.asarray(wrist, dtype=np.float64)[ok]
    if len(event_times):
        seg = CycleSegmenter(dataclasses.replace(base, mode="events"))
        for te in sorted(event_times):
            seg.add_event(float(te))
        found = [seg.update(tt, ww) + seg.update(np.zeros(0), np.zeros((0, 3)))]
    else:  # both detectors in one pass
        found = list(path_and_reach(tt, ww, base))
    return most_movements(found)


def most_movements(found: Sequence[Sequence[Boundary]]) -> list[dict[str, Any]]:
    """The movements (``{"start", "end"}``, s) of the detector (its boundaries, in
    :func:`wearable_movements`' order) that finds the most; the first wins a tie."""
    best: list[dict[str, Any]] = []
    for bounds in found:
        got = [
            {"start": float(b.cycle_start), "end": float(b)}
            for b in bounds
            if b.cycle_start is not None
        ]
        if len(got) > len(best):
            best = got
    return best


def wearable_sections(
    t: NDArray[np.float64],
    joints: Mapping[str, NDArray[np.float64]],
    valid: NDArray[np.bool_] | None = None,
    movements: Sequence[Mapping[str, Any]] | None = None,
    event_times: Sequence[float] = (),
    side: anatomy.Side = "right",
    cache: Cache | None = None,
) -> dict[str, Any]:
    """The clinical sections of a wearable session (contract §8), the same keys as
    :func:`sections`' plus ``movements``:

    - ``t`` (N,) s increasing, one row per upper-arm IMU sample;
    - ``joints``: joints.csv's columns by name (N,) each: the five joint angles (°) and
      ``wrist_x``/``wrist_y``/``wrist_z`` (m, in S); NaN where not available;
    - ``valid`` (N,) bool: the rows to use (e.g. not inside the start's rest window); all if
      None;
    - ``movements``: ``{"start", "end"}`` (s) per movement, or None to find them with
      :func:`wearable_movements` (from ``event_times``, the contract's ``cycle_start``
      events, or the wrist path);
    - ``side``: the tracked arm (the §8 angles already mean the same motions on either side);
    - ``cache``: as for :func:`sections` (a live caller asking again mid-session).

    ROM per session and per movement of the ISB shoulder angles (the same names and
    convention as the robot mode's, so a patient's history shows both modes side by side),
    the elbow flexion (the same angle as contract §3's) and the model's own angles; movement
    quality of the model's wrist path per movement; the key figures."""
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    n = len(t)

    def col(name: str) -> NDArray[np.float64]:
        a = joints.get(name)
        return np.full(n, np.nan) if a is None else np.asarray(a, dtype=np.float64).reshape(-1)

    ap = anatomy.AnatomyParams(side=side)
    angles = anatomy.wearable_isb_angles(
        col("shoulder_flexion_deg"), col("shoulder_abduction_deg"), col("shoulder_rotation_deg"), ap
    )
    angles[ELBOW] = col(ELBOW)
    for name in WEARABLE_ANGLES:
        angles.setdefault(name, col(name))
    wrist = np.stack([col("wrist_x"), col("wrist_y"), col("wrist_z")], axis=1)
    # for the quality section the path turned into the robot frame's axes (x right, y forward,
    # z up; S has x forward, y left), so path_xy is seen from above the same way in both
    # modes; the measures do not depend on the axes
    wrist_rf = np.stack([-wrist[:, 1], wrist[:, 0], wrist[:, 2]], axis=1)
    mask = np.ones(n, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    if movements is None:
        movements = wearable_movements(t[mask], wrist[mask], event_times)
    moves = [{"start": float(m["start"]), "end": float(m["end"])} for m in movements]
    rom = {
        "reference_frame": "shoulder frame S (wearable)",
        "note": WEARABLE_FRAME_NOTE,
        "convention": ISB_NOTE.format(min_elev=ap.min_elevation_deg),
        "side": side,
        **rom_section(t, angles, moves, mask, cache),
    }
    quality = quality_section(t, wrist_rf, moves, cache=cache)
    quality["source"] = "wrist (wearable model)"
    quality["note"] = WEARABLE_QUALITY_NOTE
    elbow = rom["session"].get(ELBOW, {})
    figures = [f for f in key_figures([], rom, quality) if f["key"] != "compensatory_cycles_pct"]
    figures.insert(
        1,
        {
            "key": "elbow_flexion_range_deg",
            "label": "Elbow flexion, active range (p5-p95)",
            "value": elbow.get("range"),
            "unit": "deg",
            "detail": _span(elbow),
        },
    )
    return {
        "movements": moves,
        "anatomical_rom": rom,
        "movement_quality": quality,
        "key_figures": figures,
    }


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _span(r: Mapping[str, Any]) -> str:
    if r.get("p5") is None:
        return "no data"
    return f"{r['p5']:.0f} to {r['p95']:.0f} deg"


def summary_part(report: Mapping[str, Any]) -> dict[str, Any]:
    """What a session's summary keeps of the clinical sections, for the patient's history
    and its trends without reading every report: the session ROM per angle and the movement
    quality's session medians (None for a report without them)."""
    rom = report.get("anatomical_rom")
    quality = report.get("movement_quality")
    return {
        "anatomical_rom_deg": rom.get("session") if isinstance(rom, Mapping) else None,
        "movement_quality_median": (
            quality.get("session_median") if isinstance(quality, Mapping) else None
        ),
    }
