"""Database: declarative base with a naming convention, engine and session factories."""

from backend.db.base import Base
from backend.db.session import create_engine_from_url, make_session_factory

__all__ = ["Base", "create_engine_from_url", "make_session_factory"]
