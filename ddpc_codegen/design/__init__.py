"""The design layer, offline: data -> Hankel / PE -> predictor -> steering QP (CasADi).

Modules: :mod:`.data` (IODataset, PRBS), :mod:`.hankel` (block / mosaic Hankel, PE check),
:mod:`.predictor` (pem / lsq predictors by streamed TSQR), :mod:`.artificial_io` (hopping:
ground-phase completion, hop stitching), :mod:`.config` (SteeringConfig TOML), :mod:`.problem`
(the condensed QP and its interpreted solvers), :mod:`.deepc` (the uncondensed DeePC reference),
:mod:`.result` (SteeringResult, shared with the runtime), :mod:`.phases` (phase labels).
Never imports the simulator, the robot side or the bridge.
"""
