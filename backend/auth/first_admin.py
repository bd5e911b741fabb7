"""The first admin account, created on first start.

Its random password goes to ``data_dir/admin-credentials.txt`` (0600) so that ``rehab demo``
can print it; the file is removed when that admin changes the password.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass

from sqlalchemy import func, select
from sqlalchemy.ext.asyncio import AsyncSession

from backend.auth.passwords import hash_password_async
from backend.auth.secret import write_private
from backend.db.audit import audit
from backend.db.models import Therapist
from backend.settings import Settings


@dataclass(frozen=True, slots=True)
class AdminCredentials:
    username: str
    password: str


async def ensure_first_admin(db: AsyncSession, settings: Settings) -> AdminCredentials | None:
    """Create the admin if there is no account at all; return its credentials if created.

    The password is read from ``admin_password_file`` if configured (then nothing is written),
    else generated and written to the credentials file.
    """
    if await db.scalar(select(func.count()).select_from(Therapist)):
        return None
    from_file = settings.admin_password_file is not None
    if settings.admin_password_file is not None:
        password = settings.admin_password_file.read_text(encoding="utf-8").strip()
        if not password:
            raise ValueError(f"{settings.admin_password_file} is empty")
    else:
        password = secrets.token_urlsafe(18)
    admin = Therapist(
        username=settings.admin_username,
        password_hash=await hash_password_async(password),
        is_admin=True,
        active=True,
    )
    db.add(admin)
    await db.flush()
    audit(db, None, "therapist.create", f"therapist:{admin.id}", {"first_admin": True})
    creds = AdminCredentials(settings.admin_username, password)
    if not from_file:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        write_private(
            settings.admin_credentials_file,
            f"username: {creds.username}\npassword: {creds.password}\n",
        )
    return creds


def read_admin_credentials(settings: Settings) -> AdminCredentials | None:
    """The first admin's credentials as written at first start (``None`` if not there)."""
    path = settings.admin_credentials_file
    if not path.exists():
        return None
    fields = dict(
        line.split(": ", 1)
        for line in path.read_text(encoding="utf-8").splitlines()
        if ": " in line
    )
    if "username" not in fields or "password" not in fields:
        return None
    return AdminCredentials(fields["username"], fields["password"])
