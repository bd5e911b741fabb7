"""The session report as a one- or two-page PDF (reportlab; plots by matplotlib, Agg).

Order, as a therapist reads it: the key figures, then the plots (the wrist path from above per
cycle coloured by verdict; each cycle's time outside tolerance; its smoothness), the range of
motion in anatomical terms, the movement quality's session medians, and the cycle summary
(up to :data:`MAX_CYCLE_ROWS` rows; the JSON and CSV exports hold them all).
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from datetime import datetime
from typing import Any

from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from reportlab.lib import colors
from reportlab.lib.pagesizes import A4
from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
from reportlab.lib.units import mm
from reportlab.platypus import (
    Image,
    Paragraph,
    SimpleDocTemplate,
    Spacer,
    Table,
    TableStyle,
)

from backend.exports import ExportMeta
from backend.exports.fhir import QUALITY_NAMES

MAX_CYCLE_ROWS = 40
OK_COLOUR = "#2e7d32"
COMP_COLOUR = "#c62828"
MOVE_COLOUR = "#1565c0"  # a wearable session's movements: no verdict
ELBOW_COLOUR = "#ef6c00"
_ANGLES = {
    "shoulder_plane_of_elevation_deg": "Shoulder plane of elevation",
    "shoulder_elevation_deg": "Shoulder elevation",
    "shoulder_axial_rotation_deg": "Shoulder axial rotation",
    "elbow_flexion_deg": "Elbow flexion",
    "shoulder_flexion_deg": "Shoulder flexion (model)",
    "shoulder_abduction_deg": "Shoulder abduction (model)",
    "shoulder_rotation_deg": "Shoulder int. rotation (model)",
    "forearm_pronation_deg": "Forearm pronation (model)",
}


def _wearable(report: Mapping[str, Any]) -> bool:
    return report.get("mode") == "wearable"


def _colour(c: Mapping[str, Any]) -> str:
    comp = c.get("compensatory")
    return MOVE_COLOUR if comp is None else COMP_COLOUR if comp else OK_COLOUR


def _fmt(v: Any, digits: int = 1, scale: float = 1.0) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{float(v) * scale:.{digits}f}"


def _when(t: datetime | None) -> str:
    return t.strftime("%Y-%m-%d %H:%M") if t is not None else "–"


def _plots(report: Mapping[str, Any], max_outside: float) -> bytes:
    wearable = _wearable(report)
    cycles = report.get("movements", []) if wearable else report.get("cycles", [])
    quality = report.get("movement_quality", {}).get("cycles", [])
    unit = "movement" if wearable else "cycle"
    # a Figure without pyplot: no global state, safe in the service's worker threads
    fig = Figure(figsize=(7.4, 2.5), dpi=150)
    axes = fig.subplots(1, 3)
    ax = axes[0]
    # one collection per plot, not an artist per cycle: an hour's ~700 cycles draw at once
    paths = [c for c in quality if len(c.get("path_xy") or []) > 1]
    ax.add_collection(
        LineCollection(
            [[(x * 100, y * 100) for x, y in c["path_xy"]] for c in paths],  # right, forward
            colors=[_colour(c) for c in paths],
            linewidths=0.8,
        )
    )
    ax.autoscale_view()
    ax.set_title("Wrist path from above", fontsize=8)
    ax.set_xlabel("right (cm)", fontsize=7)
    ax.set_ylabel("forward (cm)", fontsize=7)
    ax.set_aspect("equal", adjustable="datalim")
    n = range(1, len(cycles) + 1)
    ax = axes[1]
    if wearable:  # no verdicts: the active range of the two key angles per movement
        per = report.get("anatomical_rom", {}).get("cycles", [])
        for name, colour, label in (
            ("shoulder_elevation_deg", MOVE_COLOUR, "shoulder elevation"),
            ("elbow_flexion_deg", ELBOW_COLOUR, "elbow flexion"),
        ):
            pts = [
                (i, r)
                for i, c in enumerate(per, start=1)
                if (r := c["angles"].get(name, {}).get("range")) is not None
            ]
            ax.plot(
                [i for i, _ in pts],
                [r for _, r in pts],
                "-o",
                ms=2.5,
                lw=0.8,
                color=colour,
                label=label,
            )
        ax.set_ylim(bottom=0)
        ax.legend(fontsize=6, loc="lower right")
        ax.set_title("Active range per movement", fontsize=8)
        ax.set_ylabel("degrees (p5-p95)", fontsize=7)
    else:
        ax.vlines(  # bars as one line collection, as wide as the cycles allow
            list(n),
            0,
            [100 * c["outside_fraction"] for c in cycles],
            colors=[_colour(c) for c in cycles],
            linewidths=max(0.5, min(6.0, 250.0 / max(len(cycles), 1))),
        )
        ax.set_ylim(bottom=0)
        ax.axhline(100 * max_outside, color="0.3", lw=0.8, ls="--")
        ax.set_title("Time outside tolerance per cycle", fontsize=8)
        ax.set_ylabel("% of the cycle", fontsize=7)
    ax.set_xlabel(unit, fontsize=7)
    ax = axes[2]
    sparc = [c.get("sparc") for c in quality]
    ax.plot(
        [i for i, s in zip(n, sparc, strict=False) if s is not None],
        [s for s in sparc if s is not None],
        "-o",
        ms=2.5,
        lw=0.8,
        color="#1565c0",
    )
    ax.set_title(f"Smoothness (SPARC) per {unit}", fontsize=8)
    ax.set_xlabel(unit, fontsize=7)
    for a in axes[1:]:
        a.xaxis.set_major_locator(MaxNLocator(integer=True))
    for a in axes:
        a.tick_params(labelsize=6)
        a.grid(alpha=0.3, lw=0.4)
    fig.tight_layout(pad=0.4)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")  # Agg
    return buf.getvalue()


def _table(rows: Sequence[Sequence[Any]], widths: Sequence[float], font: float = 7.5) -> Table:
    t = Table([list(r) for r in rows], colWidths=list(widths), repeatRows=1, hAlign="LEFT")
    t.setStyle(
        TableStyle(
            [
                ("FONT", (0, 0), (-1, -1), "Helvetica", font),
                ("FONT", (0, 0), (-1, 0), "Helvetica-Bold", font),
                ("LINEBELOW", (0, 0), (-1, 0), 0.5, colors.grey),
                ("ALIGN", (1, 0), (-1, -1), "RIGHT"),
                ("TOPPADDING", (0, 0), (-1, -1), 1),
                ("BOTTOMPADDING", (0, 0), (-1, -1), 1),
                ("ROWBACKGROUNDS", (0, 1), (-1, -1), [colors.white, colors.HexColor("#f3f3f3")]),
            ]
        )
    )
    return t


def render(report: Mapping[str, Any], meta: ExportMeta) -> bytes:
    """The PDF's bytes."""
    styles = getSampleStyleSheet()
    small = ParagraphStyle("small", parent=styles["Normal"], fontSize=7, leading=8.5)
    h2 = ParagraphStyle("h2", parent=styles["Heading3"], fontSize=10, spaceBefore=5, spaceAfter=2)
    story: list[Any] = []
    title = f"Session report: patient {meta.patient_code or '–'}, session {meta.session}"
    if meta.provisional:
        title += " (provisional: the session is running)"
    story.append(Paragraph(title, styles["Title"]))
    summary = report.get("summary", {})
    duration = ""
    if meta.started_at and meta.stopped_at:
        duration = f", {(meta.stopped_at - meta.started_at).total_seconds() / 60:.0f} min"
    story.append(
        Paragraph(
            f"{_when(meta.started_at)}{duration} · device {meta.device} · therapist "
            f"{meta.therapist or '–'} · "
            + (
                f"wearable mode, {summary.get('movements', 0)} movements"
                if _wearable(report)
                else f"{summary.get('cycles', 0)} cycles judged"
            ),
            small,
        )
    )
    story.append(Spacer(1, 3 * mm))

    # key figures: three boxes
    figs = report.get("key_figures", [])
    cells = []
    for f in figs:
        unit = {"1": "", "%": " %", "deg": "°"}.get(f["unit"], f" {f['unit']}")
        digits = 2 if f["unit"] == "1" else 0
        cells.append(
            Paragraph(
                f"<font size=8>{f['label']}</font><br/><font size=18><b>"
                f"{_fmt(f['value'], digits)}{unit}</b></font><br/>"
                f"<font size=7 color='#555555'>{f.get('detail') or ''}</font>",
                ParagraphStyle("kf", parent=styles["Normal"], leading=20, alignment=1),
            )
        )
    if cells:
        kt = Table([cells], colWidths=[60 * mm] * len(cells))
        kt.setStyle(
            TableStyle(
                [
                    ("BOX", (0, 0), (-1, -1), 0.6, colors.grey),
                    ("INNERGRID", (0, 0), (-1, -1), 0.6, colors.grey),
                    ("BACKGROUND", (0, 0), (-1, -1), colors.HexColor("#eef4fb")),
                    ("VALIGN", (0, 0), (-1, -1), "MIDDLE"),
                ]
            )
        )
        story.append(kt)
    story.append(Spacer(1, 3 * mm))

    max_outside = float(report.get("params", {}).get("max_outside_fraction", 0.2))
    png = _plots(report, max_outside)
    story.append(Image(io.BytesIO(png), width=186 * mm, height=186 * mm * 2.5 / 7.4))
    caption = (
        "The wrist path of the wearable model (forearm IMU and the DH chain) per movement; "
        "the wearable mode judges no compensation."
        if _wearable(report)
        else f"Green: cycle within tolerance; red: compensatory (shoulder outside tolerance "
        f"for more than {100 * max_outside:.0f} % of the cycle, dashed line)."
    )
    story.append(Paragraph(caption, small))

    rom = report.get("anatomical_rom", {})
    story.append(Paragraph("Range of motion (degrees)", h2))
    rows: list[list[Any]] = [["Angle", "min", "max", "p5", "p95", "active range (p5–p95)"]]
    for name, s in rom.get("session", {}).items():
        rows.append(
            [_ANGLES.get(name, name)]
            + [_fmt(s.get(k), 0) for k in ("min", "max", "p5", "p95", "range")]
        )
    story.append(_table(rows, [55 * mm, 18 * mm, 18 * mm, 18 * mm, 18 * mm, 35 * mm]))
    if rom.get("note"):
        story.append(Paragraph(f"{rom['note']} {rom.get('convention', '')}", small))

    quality = report.get("movement_quality", {})
    unit = "movements" if _wearable(report) else "cycles"
    story.append(Paragraph(f"Movement quality (session medians over the {unit})", h2))
    med = quality.get("session_median", {})
    rows = [["Measure", "median", "unit"]]
    for k, (label, unit) in QUALITY_NAMES.items():
        rows.append([label, _fmt(med.get(k), 2 if unit in ("1", "m", "m/s") else 1), unit])
    story.append(_table(rows, [70 * mm, 25 * mm, 20 * mm]))
    if quality.get("note"):
        story.append(Paragraph(quality["note"], small))

    q_by = {(c["start"], c["end"]): c for c in quality.get("cycles", [])}
    rom_by = {(c["start"], c["end"]): c["angles"] for c in rom.get("cycles", [])}
    if _wearable(report):
        story.extend(_movements(report, q_by, rom_by, small, h2))
        return _build(story, title)
    story.append(Paragraph("Cycles", h2))
    rows = [
        [
            "#",
            "start (s)",
            "duration (s)",
            "verdict",
            "outside (%)",
            "max disp. (cm)",
            "elevation range (°)",
            "path (m)",
            "straightness",
            "units",
            "SPARC",
        ]
    ]
    cycles = report.get("cycles", [])
    for i, c in enumerate(cycles[:MAX_CYCLE_ROWS], start=1):
        q = q_by.get((c["start"], c["end"]), {})
        elev = rom_by.get((c["start"], c["end"]), {}).get("shoulder_elevation_deg", {})
        rows.append(
            [
                i,
                _fmt(c["start"], 1),
                _fmt(c["end"] - c["start"], 1),
                "compensatory" if c["compensatory"] else "ok",
                _fmt(c["outside_fraction"], 0, 100),
                _fmt(c.get("max_displacement_m"), 1, 100),
                _fmt(elev.get("range"), 0),
                _fmt(q.get("path_length_m"), 2),
                _fmt(q.get("straightness_ratio"), 2),
                _fmt(q.get("movement_units"), 0),
                _fmt(q.get("sparc"), 2),
            ]
        )
    widths = [8, 15, 18, 22, 16, 20, 26, 15, 18, 12, 16]
    table = _table(rows, [w * mm for w in widths], font=6.8)
    table.setStyle(
        TableStyle(
            [
                ("TEXTCOLOR", (3, i), (3, i), colors.HexColor(COMP_COLOUR))
                for i in range(1, len(rows))
                if rows[i][3] == "compensatory"
            ]
        )
    )
    story.append(table)
    if len(cycles) > MAX_CYCLE_ROWS:
        story.append(
            Paragraph(
                f"… and {len(cycles) - MAX_CYCLE_ROWS} more cycles (all of them are in the "
                "report's JSON and the FHIR and MCAP exports).",
                small,
            )
        )
    if not cycles:
        story.append(Paragraph("No cycle was judged in this session.", small))
    return _build(story, title)


def _movements(
    report: Mapping[str, Any],
    q_by: Mapping[tuple[float, float], Mapping[str, Any]],
    rom_by: Mapping[tuple[float, float], Mapping[str, Any]],
    small: ParagraphStyle,
    h2: ParagraphStyle,
) -> list[Any]:
    """A wearable session's movement table: ROM and quality per movement."""
    out: list[Any] = [Paragraph("Movements", h2)]
    rows: list[list[Any]] = [
        [
            "#",
            "start (s)",
            "duration (s)",
            "elevation range (°)",
            "elbow range (°)",
            "path (m)",
            "straightness",
            "units",
            "SPARC",
        ]
    ]
    moves = report.get("movements", [])
    for i, c in enumerate(moves[:MAX_CYCLE_ROWS], start=1):
        key = (c["start"], c["end"])
        q, a = q_by.get(key, {}), rom_by.get(key, {})
        rows.append(
            [
                i,
                _fmt(c["start"], 1),
                _fmt(c["end"] - c["start"], 1),
                _fmt(a.get("shoulder_elevation_deg", {}).get("range"), 0),
                _fmt(a.get("elbow_flexion_deg", {}).get("range"), 0),
                _fmt(q.get("path_length_m"), 2),
                _fmt(q.get("straightness_ratio"), 2),
                _fmt(q.get("movement_units"), 0),
                _fmt(q.get("sparc"), 2),
            ]
        )
    out.append(_table(rows, [w * mm for w in (8, 16, 18, 28, 24, 16, 20, 12, 16)], font=6.8))
    if len(moves) > MAX_CYCLE_ROWS:
        out.append(
            Paragraph(f"… and {len(moves) - MAX_CYCLE_ROWS} more movements (report JSON).", small)
        )
    if not moves:
        out.append(Paragraph("No movement was found in this session.", small))
    return out


def _build(story: list[Any], title: str) -> bytes:
    buf = io.BytesIO()
    doc = SimpleDocTemplate(
        buf,
        pagesize=A4,
        leftMargin=12 * mm,
        rightMargin=12 * mm,
        topMargin=10 * mm,
        bottomMargin=10 * mm,
        title=title,
        author="rehab-tracking",
        subject="Upper-limb rehabilitation session report",
    )
    doc.build(story)
    return buf.getvalue()
