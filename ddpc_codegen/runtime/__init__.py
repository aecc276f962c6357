"""What the robot runs: the generated solver loader and the per-tick steerer.

No CasADi, no OSQP, no simulator: :mod:`.loader` (load_solver, GeneratedSolver),
:mod:`.manifest` (reading manifest.json), :mod:`.steerer` (ReferenceSteerer with fallback).
"""
