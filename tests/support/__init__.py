"""Test support shared across tests/ (importable as `tests.support`; pytest's pythonpath includes the root)."""
