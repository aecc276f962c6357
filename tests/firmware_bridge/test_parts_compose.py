"""A second front end composes the companion loop's parts without the Bridge (as the steering proxy will):
a vehicle link on a fake link, the trigger, engagement, a reference stage around a policy, the last gate and
the recorder, wired in a dozen lines; nothing of the bridge's trajectory planning is needed."""

from __future__ import annotations

import numpy as np

from ddpc_codegen.robot.state import MeasuredState
from ddpc_codegen.runtime.baselines import PassthroughPolicy
from firmware_bridge.clock import TickTrigger
from firmware_bridge.engagement import Engagement
from firmware_bridge.events import EventLog
from firmware_bridge.gate import SetpointGate
from firmware_bridge.reference_stage import ReferenceStage
from firmware_bridge.report import FlightRecorder
from firmware_bridge.tick_gate import TickGate
from firmware_bridge.ticklog import REASONS
from firmware_bridge.plausibility import TIMELINE_SAMPLES
from part_fakes import FakeLink, heartbeat, line, telemetry, vehicle

DT = 0.005


def test_a_front_end_of_its_own_composes_the_parts():
    events = EventLog(t0=0.0)
    v = vehicle(FakeLink(), events, link_timeout=1.0)
    trigger = TickTrigger(DT, lockstep=True, max_gap_fill=3)
    eng = Engagement(events, blend_rates=(0.5, 1.0), max_age=0.05)
    app_setpoint = np.array([1.2, 0.0])  # what the user's app asked for (the proxy's nominal reference)
    stage = ReferenceStage("passthrough", lambda t: np.tile(app_setpoint, (len(t), 1)), DT, policy=PassthroughPolicy())
    gate = TickGate(SetpointGate([0.2, -0.5], [3.0, 0.5], [0.01, 0.01]), events, max_step=None, max_tilt=0.35,
                    thrust_min=0.1, thrust_max=0.9, hover_thrust=0.5, max_age=None, guard_hold=0.0)
    rec = FlightRecorder(2, 2, DT, t0=0.0, lockstep=True)
    v.on_message(heartbeat(), 0.0)
    for m in line(1.0 - DT, n=TIMELINE_SAMPLES - 1):  # the first tick's sample is the time line's fifth
        v.on_message(m, -DT)
    for k in range(100):
        for m in telemetry(1.0 + k * DT, z=1.0):
            v.on_message(m, k * DT)
        assert trigger.due(k * DT, v.telem) == "event"
        age, t, n_new = trigger.timing(k * DT, v.telem)
        trigger.gap(t, v.telem)
        y = np.array([v.telem.position[2], v.telem.euler[1]])
        fresh, engaged = age <= 0.05, v.status.armed and v.status.offboard and v.heard(k * DT)
        if eng.update(engaged, t, y, float(y[0]), v.status.mode_name):
            stage.reset()
        r_nom, hold = eng.reference(app_setpoint.copy(), y, t, DT, heard=True, engaged=engaged, fresh=fresh)
        ref = stage.step(r_nom, y, eng.trajectory_time(t), hold)
        u, flags = gate.reference(ref)
        state = MeasuredState(t=t, position=v.telem.position.copy(), velocity=v.telem.velocity.copy(),
                              euler=v.telem.euler.copy(), body_rates=v.telem.rates.copy())
        rec.record(ref, u, state, now=k * DT, t_sent=k * DT, t_vehicle=t, t_traj=eng.trajectory_time(t), age=age,
                   q=(1.0, 0.0, 0.0, 0.0), thrust=0.5, field=0.5, event=True, engaged=engaged, fresh=fresh, sent=True,
                   gap=False, n_new=n_new, latency=0.0, gate=flags, armed=True, offboard=True, y_des=app_setpoint,
                   phase=0, backdate=0, contact=None, truth=v.truth)
    reasons = np.array(REASONS)[rec.rows.view()["reason"]]
    # engaged at once; blended from the measured 1.0 m toward the app's 1.2 m at 0.5 m/s, then passed through
    assert reasons[0] == "blend" and reasons[-1] == "passthrough" and eng.activations == 1
    u = rec.rows.view()["u"][:, 0]
    assert np.all(np.diff(u) >= -1e-12) and u[-1] == 1.2 and np.isclose(u[0], 1.0 + 0.5 * DT)
