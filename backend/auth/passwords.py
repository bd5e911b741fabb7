"""Password hashing with Argon2id (pwdlib, on argon2-cffi).

Hashing costs tens of milliseconds of CPU on purpose; the async variants run it in a worker
thread so the event loop (which also runs the live pipelines) never stalls on a login. A
``limiter`` (the service's ``password_slots``) bounds how many run at once, so a burst of
logins cannot take every core from the live pipelines.
"""

from __future__ import annotations

from anyio import CapacityLimiter, to_thread
from pwdlib import PasswordHash
from pwdlib.hashers.argon2 import Argon2Hasher

_hasher = PasswordHash((Argon2Hasher(),))

# Verified against when the username is unknown, so timing does not reveal which names exist.
_DUMMY_HASH = _hasher.hash("not a password of anyone")


def hash_password(password: str) -> str:
    return _hasher.hash(password)


def verify_password(password: str, password_hash: str | None) -> tuple[bool, str | None]:
    """``(ok, new_hash)``; ``new_hash`` is set when the stored hash uses outdated parameters."""
    if password_hash is None:
        _hasher.verify(password, _DUMMY_HASH)
        return False, None
    return _hasher.verify_and_update(password, password_hash)


async def hash_password_async(password: str, limiter: CapacityLimiter | None = None) -> str:
    return await to_thread.run_sync(hash_password, password, limiter=limiter)


async def verify_password_async(
    password: str, password_hash: str | None, limiter: CapacityLimiter | None = None
) -> tuple[bool, str | None]:
    return await to_thread.run_sync(verify_password, password, password_hash, limiter=limiter)
