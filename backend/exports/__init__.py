"""Session exports for a clinic's records and for study archives, built from what
``rehab analyze`` (or the live service) wrote: the PDF report (:mod:`.pdf`), the FHIR R4
Bundle (:mod:`.fhir`) and the MCAP file of the recording and estimates (:mod:`.mcap_file`).

All three take the ``report.json`` object and an :class:`ExportMeta`; none reads the
database, so ``rehab export`` builds the same files offline.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime


@dataclass(frozen=True, slots=True)
class ExportMeta:
    """Who and when: ``session`` names the session (its id, or the recording's name offline);
    ``patient_code`` is the pseudonymous code (never a name); times are timezone-aware."""

    session: str
    device: str
    patient_code: str | None = None
    started_at: datetime | None = None
    stopped_at: datetime | None = None
    therapist: str | None = None
    provisional: bool = False
