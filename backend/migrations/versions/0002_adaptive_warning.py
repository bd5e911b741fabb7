"""A patient's tolerated time outside may be adaptive: patients.warning_after_s nullable.

NULL selects the adaptive duration (max_outside_fraction × the last cycle's duration), as
``warning_after_s: null`` does in the session parameters.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-29
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | Sequence[str] | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("patients") as batch:
        batch.alter_column("warning_after_s", existing_type=sa.Float(), nullable=True)


def downgrade() -> None:
    # The fixed default of before (contract: the paper's ~1 s) for adaptive patients.
    op.execute(sa.text("UPDATE patients SET warning_after_s = 1.0 WHERE warning_after_s IS NULL"))
    with op.batch_alter_table("patients") as batch:
        batch.alter_column("warning_after_s", existing_type=sa.Float(), nullable=False)
