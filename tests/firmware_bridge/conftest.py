"""Fixtures of the bridge tests (defined in :mod:`bridge_helpers`, registered here)."""

from support.bridge_helpers import fake_vehicle_factory, flying_solver, procs  # noqa: F401 (fixture registration)
