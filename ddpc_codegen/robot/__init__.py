"""The robot side of the closed loop: the companion controller (:mod:`.controller`), what it reads
and writes each tick (:mod:`.state`), its nominal hop cycle (:mod:`.hop_cycle`) and hopping phase
detection (:mod:`.phases`), desired trajectories (:mod:`.trajectory`, :mod:`.trajectory_files`,
:mod:`.hop_targets`), rotations / frame conversions (:mod:`.frames`) and robot profiles
(:mod:`.profile`). Runs in the simulator and, through the MAVLink bridge, on the companion
computer; imports neither the simulator nor CasADi.
"""
