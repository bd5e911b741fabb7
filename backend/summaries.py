"""Session summaries for lists: sessions stored before a summary key existed (the range of
motion) or without a summary (stopped while the live side did not have them) get theirs
from the report stored beside their recording, once; the result is kept in the table.

Reading a stored report this way is not an export (nothing leaves the service), so it is
not audited; the report endpoints are.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from backend.db.models import Session
from backend.live import files
from backend.live.worker import summary_of

log = logging.getLogger(__name__)

# Keys a complete summary has (None values included: the report had nothing to give).
RANGE_KEYS = ("elbow_flexion_deg", "upper_arm_elevation_deg", "upper_arm_azimuth_deg")


def incomplete(session: Session) -> bool:
    """A finished session with a recording whose summary lacks the range of motion."""
    if session.status == "active" or session.recording_path is None:
        return False
    return session.summary is None or any(k not in session.summary for k in RANGE_KEYS)


def _read_report(path: Path) -> dict[str, Any] | None:
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None  # not written yet (interrupted: written on recovery or first export)
    except (OSError, ValueError):
        log.warning("unreadable report %s", path, exc_info=True)
        return None
    return report if isinstance(report, dict) else None


def from_report(report: dict[str, Any]) -> dict[str, Any] | None:
    """The summary the live side stores when a session stops, from a stored report."""
    try:
        return summary_of(report)
    except (KeyError, TypeError, AttributeError):
        return None  # a report of another shape: leave the session as it is


async def complete_summaries(sessions: Iterable[Session], data_dir: Path) -> bool:
    """Fill in what the summaries of ``sessions`` lack from their stored reports (the
    stored keys win). Return whether any changed: the caller commits."""
    changed = False
    for session in sessions:
        if not incomplete(session) or session.recording_path is None:
            continue
        try:
            recording = files.resolve(data_dir, session.recording_path)
        except ValueError:
            continue
        path = files.outputs_dir(recording) / "report.json"
        report = await asyncio.to_thread(_read_report, path)
        summary = from_report(report) if report is not None else None
        if summary is None:
            continue
        session.summary = {**summary, **(session.summary or {})}
        changed = True
    return changed
