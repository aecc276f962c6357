"""Import options the ULog and tlog importers share: their checks, the time-range crop, and how
they are recorded in the dataset's settings."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.notes import Notes
from ddpc_codegen.logs.resample import Segment, Window, build_segments
from ddpc_codegen.logs.series import Series

__all__ = ["ImportOptions", "check_on_nan", "check_time_range", "crop_window", "gap_rule_text"]


@dataclass(frozen=True)
class ImportOptions:
    """The options of :func:`~ddpc_codegen.logs.import_ulog` that apply to every log format
    (see there); the importers check them before building one."""

    rate_hz: float
    max_gap: float | None
    gap_factor: float
    min_duration: float
    offboard_only: bool
    armed_only: bool
    split_on_mode: bool
    time_range: tuple[float, float] | None
    input_rule: str
    output_rule: str
    on_nan: str

    @property
    def filters_modes(self) -> bool:
        """Whether a mode filter is asked for (then the log's mode reports must be read)."""
        return self.offboard_only or self.armed_only or self.split_on_mode

    def segments(self, inputs: Sequence[Series], outputs: Sequence[Series], *, origin_us: int, notes: Notes,
                 windows: Sequence[Window] | None, what: str, rate_hint: str = "") -> list[Segment]:
        """:func:`~ddpc_codegen.logs.resample.build_segments` with these options."""
        return build_segments(inputs, outputs, rate_hz=self.rate_hz, origin_us=origin_us, notes=notes,
                              windows=windows, max_gap_s=self.max_gap, gap_factor=self.gap_factor,
                              min_duration_s=self.min_duration, what=what, rate_hint=rate_hint)

    def mode_filter_settings(self) -> dict[str, bool]:
        """The mode filter as recorded in the dataset's settings."""
        return {"offboard_only": self.offboard_only, "armed_only": self.armed_only,
                "split_on_mode": self.split_on_mode}


def check_on_nan(on_nan: str) -> None:
    """``on_nan`` must be "drop" or "error"."""
    if on_nan not in ("drop", "error"):
        raise DataError(f"on_nan must be 'drop' or 'error'; got {on_nan!r}")


def check_time_range(time_range: tuple[float, float] | None) -> None:
    """A time range, if given, must end after it starts."""
    if time_range is not None and not float(time_range[1]) > float(time_range[0]):
        raise DataError(f"time_range end must be after start; got {time_range[0]}..{time_range[1]} s")


def crop_window(origin_us: int, time_range: tuple[float, float] | None) -> tuple[int, int] | None:
    """The half-open [a, b) µs window of ``time_range`` (s since ``origin_us``), end included."""
    if time_range is None:
        return None
    return (origin_us + int(round(float(time_range[0]) * 1e6)), origin_us + int(round(float(time_range[1]) * 1e6)) + 1)


def gap_rule_text(max_gap: float | None, gap_factor: float) -> str:
    """The gap rule in words, for the dataset's settings."""
    return (f"split at spells > {max_gap} s without samples" if max_gap is not None
            else f"split at spells > {gap_factor:g} x the channel's median sampling interval")
