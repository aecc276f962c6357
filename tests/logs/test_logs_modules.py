"""The log importers' modules after the split (issue 11): old import paths keep working."""

from __future__ import annotations

import importlib

import ddpc_codegen.logs as logs
from ddpc_codegen.logs import channels, grid, intervals, notes, resample, series, tlog, tlog_reader


def test_resample_still_exports_every_name_of_the_rule():
    for name in resample.__all__:
        assert hasattr(resample, name), name
    # the same objects as in their new homes, so isinstance / except / warning filters still match
    assert resample.ChannelSpec is channels.ChannelSpec and resample.parse_channel_spec is channels.parse_channel_spec
    assert resample.Series is series.Series and resample.clean_series is series.clean_series
    assert resample.LogImportWarning is notes.LogImportWarning is logs.LogImportWarning
    assert resample.state_windows is intervals.state_windows and resample.uniform_grid is grid.uniform_grid
    assert resample.RULES == ("hold", "linear", "cubic")


def test_tlog_still_exports_the_reader():
    assert tlog.read_tlog is tlog_reader.read_tlog is logs.read_tlog
    assert tlog.list_tlog_messages is tlog_reader.list_tlog_messages


def test_package_exports_unchanged():
    assert set(logs.__all__) == {
        "import_ulog", "import_tlog", "read_tlog", "list_ulog_topics", "list_tlog_messages", "ULOG_PRESETS",
        "TLOG_PRESETS", "ChannelSpec", "parse_channel_spec", "LogImportWarning", "RESAMPLING_RULE",
        "euler_from_quat_array", "quat_from_euler_array", "enu_from_ned_array", "up_from_down_array",
        "yaw_enu_from_ned_array",
    }
    for name in logs.__all__:
        assert getattr(importlib.import_module("ddpc_codegen.logs"), name) is not None
