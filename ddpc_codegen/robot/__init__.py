"""The robot side of the closed loop: the companion controller (:mod:`.controller`),
desired trajectories (:mod:`.trajectory`) and rotations / frame conversions (:mod:`.frames`).
Runs in the simulator and, through the MAVLink bridge, on the companion computer; imports
neither the simulator nor CasADi.
"""
