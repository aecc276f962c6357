"""Flight logs -> IODataset: PX4 ULog (pyulog) and MAVLink telemetry logs (pymavlink).

Inputs are the setpoints that were sent (held between samples, as the autopilot holds them),
outputs what the vehicle did (interpolated), both resampled onto the controller's uniform grid
and split into trajectories at gaps and mode changes; see :mod:`.resample` for the exact rule.
Bad logs raise :class:`~ddpc_codegen.errors.DataError` naming the topic and time range, or
warn (:class:`LogImportWarning`) saying what was dropped; nothing is silently invented.

Modules, in the order the data flows: ``ulog`` / ``tlog`` (read a log, pick the channels, mode
windows; ``tlog_reader`` frames and decodes .tlog records), ``channels`` (spec grammar, presets),
``series`` (one channel validated), ``intervals`` (coverage, gaps, mode windows), ``grid`` (one
channel onto the grid), ``resample`` (the rule: channels -> trajectories), ``dataset`` (the
IODataset and its provenance); ``options`` and ``notes`` are shared by both importers.
"""

from ddpc_codegen.logs.resample import RESAMPLING_RULE, ChannelSpec, LogImportWarning, parse_channel_spec
from ddpc_codegen.logs.tlog import TLOG_PRESETS, import_tlog, list_tlog_messages, read_tlog
from ddpc_codegen.logs.ulog import ULOG_PRESETS, import_ulog, list_ulog_topics
from ddpc_codegen.robot.frames import (  # the log importers' frame math, re-exported
    enu_from_ned_array,
    euler_from_quat_array,
    quat_from_euler_array,
    up_from_down_array,
    yaw_enu_from_ned_array,
)

__all__ = [
    "import_ulog",
    "import_tlog",
    "read_tlog",
    "list_ulog_topics",
    "list_tlog_messages",
    "ULOG_PRESETS",
    "TLOG_PRESETS",
    "ChannelSpec",
    "parse_channel_spec",
    "LogImportWarning",
    "RESAMPLING_RULE",
    "euler_from_quat_array",
    "quat_from_euler_array",
    "enu_from_ned_array",
    "up_from_down_array",
    "yaw_enu_from_ned_array",
]
