"""The app -> vehicle setpoint path decides the outgoing bytes first and does the rest after the send: a settling
hook's ``settle`` and a passive hook's whole call come after the vehicle's write, with the same bytes out; the
faster pieces on that path (the setpoint decode, the replacement's encoding, the app's period, the steerer's bound
check) give exactly what pymavlink, numpy and the bounds give."""

from __future__ import annotations

import random
import time

import numpy as np

from ddpc_codegen.runtime.steerer import ReferenceSteerer
from ddpc_codegen.values.solve_result import BOUND_TOL, SteeringResult
from firmware_bridge.proxy.rewrite import PROXY_COMPONENT, SetpointEncoder, decode_frame, decode_setpoint, mavlink
from firmware_bridge.proxy.stats import SetpointPeriod

from proxy_support import POS_ONLY, Peer, RunningProxy, frames, free_port, mav, setpoint


def _random_setpoints(n: int, seed: int):
    """n decoded (message, frame) pairs of both setpoint messages, MAVLink 1 and 2, with zeros, nan and inf."""
    rnd = random.Random(seed)

    def f32() -> float:
        return rnd.choice([0.0, -0.0, 1.5, float("nan"), float("inf"), rnd.uniform(-1e3, 1e3), 0.0])

    for _ in range(n):
        a = mavlink.MAVLink(None, srcSystem=rnd.choice([1, 245, 255]), srcComponent=rnd.choice([1, 190]))
        a.seq = rnd.randrange(256)
        head = (rnd.randrange(2 ** 32), rnd.randrange(256), rnd.randrange(256))
        if rnd.random() < 0.5:
            msg = a.set_position_target_local_ned_encode(*head, rnd.choice([1, 8]), rnd.choice([0, rnd.randrange(65536)]),
                                                         *[f32() for _ in range(11)])
        else:
            msg = a.set_position_target_global_int_encode(*head, rnd.choice([5, 6, 0]), rnd.randrange(65536),
                                                          rnd.randrange(-2 ** 31, 2 ** 31), rnd.randrange(-2 ** 31, 2 ** 31),
                                                          *[f32() for _ in range(9)])
        frame = bytes(msg.pack(a, force_mavlink1=rnd.random() < 0.3))
        yield decode_frame(frame), frame


def _pymavlink_encode(mavs: dict, msg, position_ned=None, **fields) -> bytes:
    """The replacement as pymavlink makes it: a message object of the same fields, packed by a MAVLink per system."""
    sysid = msg.get_srcSystem()
    m = mavs.setdefault(sysid, mavlink.MAVLink(None, srcSystem=sysid, srcComponent=PROXY_COMPONENT))
    values = {f: getattr(msg, f) for f in type(msg).fieldnames}
    if position_ned is not None:
        values["x"], values["y"], values["z"] = (float(v) for v in position_ned)
    values.update(fields)
    out = bytes(type(msg)(**values).pack(m))
    m.seq = (m.seq + 1) % 256
    return out


def test_the_encoder_makes_pymavlinks_own_frame():
    enc, mavs, rnd = SetpointEncoder(), {}, random.Random(5)
    for msg, _ in _random_setpoints(2000, seed=1):
        local = msg.get_msgId() == mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
        kw = rnd.choice([{}, {"vz": 0.0, "afz": 0.0}, {"z" if local else "alt": rnd.uniform(-5, 5)}])
        pos = (rnd.uniform(-5, 5), 1.0, float("nan")) if local and rnd.random() < 0.3 else None
        assert enc.encode(msg, pos, **kw) == _pymavlink_encode(mavs, msg, pos, **kw)


def test_the_setpoint_decode_is_pymavlinks():
    for msg, frame in _random_setpoints(2000, seed=2):
        fast = decode_setpoint(frame)
        a, b = dict(vars(msg)), dict(vars(fast))
        assert vars(a.pop("_header")) == vars(b.pop("_header"))
        assert a.keys() == b.keys()
        for k, v in a.items():
            assert type(v) is type(b[k]) and (v == b[k] or v != v and b[k] != b[k]), k
    assert decode_setpoint(frames(mav(2, 1, 1), 1)[0]).get_type() == "HEARTBEAT"  # not a setpoint: pymavlink's


def test_the_period_is_numpys_median():
    rng = np.random.default_rng(0)
    for size in (5, 64):
        p, t = SetpointPeriod(ring_size=size), 0.0
        assert p.period() is None
        for _ in range(150):
            t += float(rng.uniform(0.01, 0.03))
            p.add(t)
            v = p.gaps.values()
            assert p.period() == (float(np.median(v)) if v.size else None)


class _Order:
    """A hook that notes when it is asked, settled and called, against the vehicle side's writes."""

    def __init__(self, passive: bool) -> None:
        self.log: list[str] = []
        self.passive, self.enc = passive, SetpointEncoder()

    def decide(self, msg, frame, t_rx):
        self.log.append("decide")
        return self.enc.encode(msg, (msg.x, msg.y, msg.z - 1.0))

    def settle(self) -> None:
        self.log.append("settle")

    def __call__(self, msg, frame, t_rx):
        self.log.append("call")


def _run(passive: bool):
    ap, vp = free_port(), free_port()
    hook = _Order(passive)
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}", rewrite=hook)
    write = rp.proxy.vehicle.write

    def logged(buf):
        hook.log.append("write")
        return write(buf)

    rp.proxy.vehicle.write = logged
    veh, app = Peer(), Peer()
    try:
        veh.send(frames(mav(2, 1, 1), 1)[0], vp)
        rp.wait_vehicle()
        a = mav(2, 245, 190)
        sent = [setpoint(a, k, POS_ONLY) for k in range(20)]
        for f in sent:
            app.send(f, ap)
            time.sleep(0.005)
        got = veh.wait_for(len(sent))
        return hook.log, sent, got, rp.stop()
    finally:
        rp.stop()
        for p in (veh, app):
            p.close()


def test_a_settling_hook_decides_before_the_send_and_settles_after_it():
    log, sent, got, s = _run(passive=False)
    assert [x for x in log if x != "write"] == ["decide", "settle"] * 20 and "call" not in log
    assert log[log.index("decide") + 1] == "write" and log[log.index("write") + 1] == "settle"
    assert len(got) == 20 and all(g != f for g, f in zip(got, sent)) and s["app_to_vehicle"]["rewritten"] == 20


def test_a_passive_hook_runs_after_the_send_and_the_apps_bytes_go_out():
    log, sent, got, s = _run(passive=True)
    assert log == ["write", "call"] * 20
    assert got == sent and s["app_to_vehicle"]["rewritten"] == 0 and s["setpoints"]["count"] == 20


class _Fixed:
    """A solver whose answer is ``u`` over the whole horizon."""

    def __init__(self) -> None:
        self.u = 0.0

    def solve(self, u_ini, y_ini, y_des, u_nom=None) -> SteeringResult:
        return SteeringResult(np.full((3, 1), self.u), status="solved")


def test_the_steerers_bound_check_follows_its_bounds_whatever_they_are_set_to():
    """The widened bounds are made once per bounds, not per tick: a bound assigned later is the one checked."""
    solver = _Fixed()
    st = ReferenceSteerer(solver, 2, 3, 1, 1, u_min=np.array([-1.0]), u_max=np.array([2.0]), has_nominal=False)
    for _ in range(2):
        st.observe(np.zeros(1), np.zeros(1))

    def reason(u: float) -> str:
        solver.u = u
        return st.step(np.zeros((3, 1)), np.zeros((3, 1))).reason

    assert reason(2.0 + 1.5 * BOUND_TOL) == "steered" and reason(2.0 + 2.5 * BOUND_TOL) == "out_of_bounds"
    assert reason(-1.0 - 0.5 * BOUND_TOL) == "steered" and reason(-1.0 - 1.5 * BOUND_TOL) == "out_of_bounds"
    st.u_max = np.array([3.0])
    assert reason(2.5) == "steered" and reason(3.1) == "out_of_bounds"
    st.u_min, st.u_max = None, None
    assert reason(-50.0) == "steered" and reason(50.0) == "steered"
