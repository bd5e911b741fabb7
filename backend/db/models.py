"""The stored records: therapists, patients, devices, sessions, cycles and the audit log.

Patients are pseudonymous: a code, the affected side and the numbers the method needs, no name.
Overlay tokens are not stored: they are signed, bound to a device and a session, and die
with the session (see :mod:`backend.auth.tokens`).
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import (
    JSON,
    CheckConstraint,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    Text,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import Mapped, mapped_column, relationship

from backend.db.base import Base, utcnow

SESSION_STATUSES = ("active", "stopped", "interrupted")
DEVICE_STATUSES = ("online", "offline")

# Contract §4 defaults; warning_after_s follows the paper's ~1 s tolerated time (method.md).
DEFAULT_ARM = {"upper_arm_length_m": 0.30, "imu_to_elbow_m": 0.15, "cuff_to_elbow_m": 0.06}
DEFAULT_TOLERANCE = {
    "tolerance_m": 0.10,
    "max_outside_fraction": 0.20,
    "displacement_norm": "horizontal",
    "warning_after_s": 1.0,
}

JSONDict = dict[str, Any]


class Therapist(Base):
    __tablename__ = "therapists"

    id: Mapped[int] = mapped_column(primary_key=True)
    username: Mapped[str] = mapped_column(String(64), unique=True)
    password_hash: Mapped[str] = mapped_column(String(255))
    is_admin: Mapped[bool] = mapped_column(default=False)
    active: Mapped[bool] = mapped_column(default=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Patient(Base):
    __tablename__ = "patients"
    __table_args__ = (
        CheckConstraint("affected_side IN ('left', 'right')", name="affected_side"),
        CheckConstraint("displacement_norm IN ('horizontal', '3d')", name="displacement_norm"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    code: Mapped[str] = mapped_column(String(64), unique=True)
    affected_side: Mapped[str] = mapped_column(String(8))
    upper_arm_length_m: Mapped[float] = mapped_column(Float)
    imu_to_elbow_m: Mapped[float] = mapped_column(Float)
    cuff_to_elbow_m: Mapped[float] = mapped_column(Float)
    tolerance_m: Mapped[float] = mapped_column(Float)
    max_outside_fraction: Mapped[float] = mapped_column(Float)
    displacement_norm: Mapped[str] = mapped_column(String(16))
    # None: adaptive, max_outside_fraction × the last cycle's duration (estimators' default)
    warning_after_s: Mapped[float | None] = mapped_column(Float)
    notes: Mapped[str] = mapped_column(Text, default="")
    created_by_id: Mapped[int | None] = mapped_column(
        ForeignKey("therapists.id", ondelete="SET NULL")
    )
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)

    created_by: Mapped[Therapist | None] = relationship(lazy="raise")

    def params(self) -> JSONDict:
        """The contract §4 parameter object (plus the tolerated duration) for this patient."""
        return {
            "upper_arm_length_m": self.upper_arm_length_m,
            "imu_to_elbow_m": self.imu_to_elbow_m,
            "cuff_to_elbow_m": self.cuff_to_elbow_m,
            "tolerance_m": self.tolerance_m,
            "max_outside_fraction": self.max_outside_fraction,
            "displacement_norm": self.displacement_norm,
            "warning_after_s": self.warning_after_s,
            "nominal_shoulder_m": None,
        }


class Device(Base):
    """A contract device id, registered by the ingest when its data first arrives."""

    __tablename__ = "devices"
    __table_args__ = (CheckConstraint("status IN ('online', 'offline')", name="status"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    first_seen: Mapped[datetime] = mapped_column(default=utcnow)
    last_seen: Mapped[datetime] = mapped_column(default=utcnow)
    status: Mapped[str] = mapped_column(String(16), default="online")
    # Last snapshot of rates and data-quality counters, as the ingest reports them.
    stats: Mapped[JSONDict | None] = mapped_column(JSON)


class Session(Base):
    """A patient on a device, from start to stop, with the parameters used."""

    __tablename__ = "sessions"
    __table_args__ = (
        CheckConstraint("status IN ('active', 'stopped', 'interrupted')", name="status"),
        # One running session per device, enforced by the database against races.
        Index(
            "uq_sessions_active_device",
            "device_id",
            unique=True,
            sqlite_where=text("status = 'active'"),
            postgresql_where=text("status = 'active'"),
        ),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    patient_id: Mapped[int] = mapped_column(ForeignKey("patients.id"), index=True)
    device_id: Mapped[int] = mapped_column(ForeignKey("devices.id"), index=True)
    therapist_id: Mapped[int | None] = mapped_column(
        ForeignKey("therapists.id", ondelete="SET NULL")
    )
    started_at: Mapped[datetime] = mapped_column(default=utcnow)
    stopped_at: Mapped[datetime | None]
    status: Mapped[str] = mapped_column(String(16), default="active")
    params: Mapped[JSONDict] = mapped_column(JSON)
    # Relative to data_dir, so a data directory can be moved as a whole.
    recording_path: Mapped[str | None] = mapped_column(String(512))
    # {"point": [x, y, z], "source": ..., "set_at": iso, "set_by": username | null}
    nominal_shoulder: Mapped[JSONDict | None] = mapped_column(JSON)
    summary: Mapped[JSONDict | None] = mapped_column(JSON)

    patient: Mapped[Patient] = relationship(lazy="raise")
    device: Mapped[Device] = relationship(lazy="raise")
    therapist: Mapped[Therapist | None] = relationship(lazy="raise")


class Cycle(Base):
    """One completed movement cycle and its verdict (times are sample times, seconds)."""

    __tablename__ = "cycles"
    __table_args__ = (UniqueConstraint("session_id", "index"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"))
    index: Mapped[int] = mapped_column(Integer)
    start: Mapped[float] = mapped_column(Float)
    end: Mapped[float] = mapped_column(Float)
    outside_fraction: Mapped[float] = mapped_column(Float)
    compensatory: Mapped[bool]
    coverage: Mapped[float | None] = mapped_column(Float)
    peak_displacement_m: Mapped[float | None] = mapped_column(Float)
    recorded_at: Mapped[datetime] = mapped_column(default=utcnow)


class AuditLog(Base):
    """Who did what to which object, and when. Rows are only ever added."""

    __tablename__ = "audit_log"

    id: Mapped[int] = mapped_column(primary_key=True)
    at: Mapped[datetime] = mapped_column(default=utcnow, index=True)
    therapist_id: Mapped[int | None] = mapped_column(
        ForeignKey("therapists.id", ondelete="SET NULL"), index=True
    )
    # Kept as text too: a failed login names a user who may not exist.
    actor: Mapped[str | None] = mapped_column(String(64))
    action: Mapped[str] = mapped_column(String(64), index=True)
    object: Mapped[str | None] = mapped_column(String(128))
    details: Mapped[JSONDict | None] = mapped_column(JSON)


class Login(Base):
    """One login: the access token names it (``sid``), so it can be ended server-side.

    Revoked by logout, a password change (the account's other logins) and deactivation; dead
    after ``expires_at`` or when unused for ``session_idle_s``. The id is random, not secret
    on its own: a token also needs the signing key.
    """

    __tablename__ = "logins"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    therapist_id: Mapped[int] = mapped_column(
        ForeignKey("therapists.id", ondelete="CASCADE"), index=True
    )
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    last_seen: Mapped[datetime] = mapped_column(default=utcnow)
    expires_at: Mapped[datetime]
    revoked_at: Mapped[datetime | None]
    ip: Mapped[str | None] = mapped_column(String(64))


class DeviceLease(Base):
    """Which worker runs a device's pipeline (see :mod:`backend.live.lease`).

    ``epoch`` grows by one at every change of holder: the fencing token a holder's writes
    are conditioned on. ``expires_at`` is the holder's wall clock (Unix seconds) plus the
    lease's time to live.
    """

    __tablename__ = "device_leases"

    device: Mapped[str] = mapped_column(String(64), primary_key=True)
    holder: Mapped[str] = mapped_column(String(64), default="")
    epoch: Mapped[int] = mapped_column(Integer, default=0)
    expires_at: Mapped[float] = mapped_column(Float, default=0.0)
