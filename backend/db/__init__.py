"""Storage: models, the database handle and the service-layer functions the live side calls."""

from backend.db.base import Base, utcnow
from backend.db.engine import Database

__all__ = ["Base", "Database", "utcnow"]
