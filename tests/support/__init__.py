"""Test support shared across the suite (imported as ``support.<module>``; tests/ is on pythonpath)."""
