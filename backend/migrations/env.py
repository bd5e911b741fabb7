"""Alembic environment.

Two ways in: the service passes its own connection (``config.attributes["connection"]``,
see :func:`backend.db.engine.Database.migrate`); the ``alembic`` command line
(``alembic -c backend/alembic.ini ...``) uses ``sqlalchemy.url`` or the ``REHAB_*`` settings.
"""

from __future__ import annotations

import asyncio
from logging.config import fileConfig

from alembic import context
from sqlalchemy import Connection
from sqlalchemy.ext.asyncio import create_async_engine

from backend.db import models  # noqa: F401  (registers the tables)
from backend.db.base import Base

target_metadata = Base.metadata

if context.config.config_file_name is not None:  # command line only: keep the app's logging
    fileConfig(context.config.config_file_name, disable_existing_loggers=False)


def _configure(connection: Connection) -> None:
    context.configure(
        connection=connection,
        target_metadata=target_metadata,
        render_as_batch=True,  # SQLite cannot ALTER most things; batch mode copies tables
        compare_type=True,
    )
    with context.begin_transaction():
        context.run_migrations()


async def _run_with_own_engine(url: str) -> None:
    engine = create_async_engine(url)
    try:
        async with engine.begin() as conn:
            await conn.run_sync(_configure)
    finally:
        await engine.dispose()


def _url() -> str:
    url = context.config.get_main_option("sqlalchemy.url")
    if url:
        return url
    from backend.settings import Settings

    return Settings().db_url


if context.is_offline_mode():
    context.configure(url=_url(), target_metadata=target_metadata, literal_binds=True)
    with context.begin_transaction():
        context.run_migrations()
else:
    conn = context.config.attributes.get("connection")
    if conn is not None:
        _configure(conn)
    else:
        asyncio.run(_run_with_own_engine(_url()))
