"""Test bed for the companion side: the PogoX simulator behind a PX4- / ArduCopter-like MAVLink
endpoint, the real-autopilot SITL harness, and the demos that fly the bridge against them.

* :mod:`.vehicle`, :mod:`.vehicle_autopilot`, :mod:`.vehicle_position`, :mod:`.vehicle_config`,
  :mod:`.vehicle_telemetry` --
  the simulated vehicle (``ddpc-vehicle``, :mod:`.cli`).
* :mod:`.sitl` -- PX4 SIH and ArduCopter SITL processes in private network namespaces.
* :mod:`.sitl_demo` -- ``make sitl-demo``: baseline, collect, codegen and steered flights on both.
* :mod:`.bridge_demo`, :mod:`.bridge_demo_hopping` -- ``make bridge-demo [SCENARIO=hopping]``.
* :mod:`.ilc` -- ILC between flights: a tick log -> the next feed-forward table.

Uses the simulator, the experiments and the bridge; nothing on the robot side imports it.
"""
