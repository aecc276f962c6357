"""Cut a real PX4 ULog down to a test fixture: a few topics, a few fields, a time window.

The fixture ``data/px4_sih_offboard_attitude.ulg`` was made from PX4 SITL (SIH quad, PX4 main
02e73e3b, default logger profile) flown by ``ddpc-bridge --mode passthrough --arm --offboard
--takeoff --land`` (attitude off-board, SET_ATTITUDE_TARGET at 200 Hz)::

    cd tests/logs && python trim_ulog.py <px4 workdir>/log/<date>/<time>.ulg data/px4_sih_offboard_attitude.ulg 3.5 13

Values and time stamps are PX4's own; only the topics / fields below and the window are kept
(the formats are trimmed PX4 formats, written with :class:`ulog_writer.ULogWriter`).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from ulog_writer import PX4_FORMATS, ULogWriter

# topic -> fields kept ([n] = array field); what the px4-offboard-attitude preset, the mode filter
# and the attitude-off-board check read.
KEEP = {
    "vehicle_status": ["arming_state", "nav_state"],
    "offboard_control_mode": ["position", "velocity", "acceleration", "attitude", "body_rate", "thrust_and_torque",
                              "direct_actuator"],
    "vehicle_attitude_setpoint": ["q_d[4]", "thrust_body[3]"],
    "vehicle_attitude": ["q[4]"],
    "vehicle_local_position": ["x", "y", "z", "vx", "vy", "vz"],
    "trajectory_setpoint": ["position[3]"],
}
_TYPES = {"vehicle_status": "uint8_t", "offboard_control_mode": "bool"}


def trim(src: str | Path, dst: str | Path, t_from: float, t_to: float) -> Path:
    """Keep ``KEEP`` between ``t_from`` and ``t_to`` [s since the log start] (vehicle_status: all)."""
    from pyulog import ULog

    log = ULog(str(src), message_name_filter_list=sorted(KEEP))
    w = ULogWriter(int(log.start_timestamp))
    w.add_info("sys_name", str(log.msg_info_dict.get("sys_name", "PX4")))
    w.add_info("ver_sw", str(log.msg_info_dict.get("ver_sw", "")))
    a, b = log.start_timestamp + int(t_from * 1e6), log.start_timestamp + int(t_to * 1e6)
    for topic, fields in KEEP.items():
        d = log.get_dataset(topic, 0).data
        t = d["timestamp"].astype(np.int64)
        sel = np.ones(t.size, bool) if topic == "vehicle_status" else (t >= a) & (t <= b)
        fmt, values = [("uint64_t", "timestamp")], {}
        for f in fields:
            name, n = (f[:-1].split("[")[0], int(f[:-1].split("[")[1])) if "[" in f else (f, 0)
            base = _TYPES.get(topic, "float")
            fmt.append((f"{base}[{n}]" if n else base, name))
            values[name] = (np.stack([d[f"{name}[{i}]"][sel] for i in range(n)], axis=1) if n else d[name][sel])
        assert topic in PX4_FORMATS
        w.add_format(topic, fmt)
        mid = w.add_subscription(topic)
        w.add_series(mid, t[sel], **values)
    return w.write(dst)


if __name__ == "__main__":
    out = trim(sys.argv[1], sys.argv[2], float(sys.argv[3]) if len(sys.argv) > 3 else 3.5,
               float(sys.argv[4]) if len(sys.argv) > 4 else 13.0)
    print(f"{out}: {out.stat().st_size} bytes")
