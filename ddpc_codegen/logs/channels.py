"""Channel specs: the ``[NAME=]SOURCE[@N].FIELD[:UNIT]`` grammar, default names and units,
and the preset + explicit channel list an import works on."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Sequence

from ddpc_codegen.errors import DataError

__all__ = ["ChannelSpec", "parse_channel_spec", "guess_unit", "check_names", "resolve_channels"]

_SPEC_RE = re.compile(
    r"""^\s*(?:(?P<name>[A-Za-z_][\w\-]*)\s*=\s*)?      # optional NAME=
        (?P<source>[A-Za-z_]\w*)                        # topic / message name
        (?:@(?P<instance>\d+))?                         # optional @instance / @sysid
        \.(?P<field>[A-Za-z_][\w\[\]\.]*?)              # field (raw or derived)
        (?::(?P<unit>[^:=]*))?\s*$                      # optional :UNIT
    """,
    re.VERBOSE,
)

# Known units by (base) field name: PX4 uORB and MAVLink agree on SI units for these.
_UNITS: dict[str, str] = {
    **{k: "rad" for k in ("roll", "pitch", "yaw", "roll_body", "pitch_body", "yaw_body", "heading")},
    **{k: "rad/s" for k in ("rollspeed", "pitchspeed", "yawspeed", "yaw_rate", "yawspeed_setpoint",
                            "body_roll_rate", "body_pitch_rate", "body_yaw_rate")},
    **{k: "m" for k in ("x", "y", "z", "position[0]", "position[1]", "position[2]", "dist_bottom")},
    **{k: "m/s" for k in ("vx", "vy", "vz", "velocity[0]", "velocity[1]", "velocity[2]")},
    **{k: "m/s^2" for k in ("ax", "ay", "az", "afx", "afy", "afz",
                            "acceleration[0]", "acceleration[1]", "acceleration[2]")},
    **{k: "1" for k in ("thrust", "thrust_body[0]", "thrust_body[1]", "thrust_body[2]")},
}


def guess_unit(field_name: str) -> str:
    """Unit of a (possibly derived) field by name; "" if unknown (then say so, don't guess)."""
    base = field_name[:-3] if field_name.endswith("_up") else field_name
    return _UNITS.get(base, "")


def _default_name(field_name: str, role: str) -> str:
    base = field_name[:-3] if field_name.endswith("_up") else field_name
    base = re.sub(r"\[(\d+)\]", r"\1", base).replace(".", "_")
    return f"{base}_ref" if role == "input" and not base.endswith("_ref") else base


@dataclass(frozen=True)
class ChannelSpec:
    """One dataset channel as asked for on the command line.

    Syntax ``[NAME=]SOURCE[@N].FIELD[:UNIT]``:

    - SOURCE: ULog topic (``vehicle_attitude``) or MAVLink message (``ATTITUDE``);
      ``@N`` is the ULog multi-instance (default 0) or the MAVLink source system id.
    - FIELD: a raw field (``z``, ``q[0]``, ``thrust_body[2]``) or a derived one:
      ``roll``/``pitch``/``yaw`` (Euler ZYX in rad from ``q`` or ``q_d``), ``F_up`` (= -F, for a
      down-pointing NED/FRD field F: ``z_up``, ``vz_up``, ``thrust_body[2]_up``).
    - NAME: the dataset channel name (default: the field, ``_up`` dropped, ``_ref`` appended for
      inputs: ``trajectory_setpoint.z_up`` -> ``z_ref``, ``vehicle_attitude.pitch`` -> ``pitch``).
    - UNIT: the unit string (default: known SI unit of the field, else ""; MAVLink logs take
      the unit from the message definition instead, see ``logs.tlog.mavlink_unit``).
    ``unit_given``: the spec stated the unit (``:UNIT``).
    """

    name: str
    source: str
    instance: int | None
    field: str
    unit: str
    text: str
    unit_given: bool = False

    @property
    def where(self) -> str:
        inst = "" if self.instance is None else f"@{self.instance}"
        return f"{self.source}{inst}.{self.field}"


def parse_channel_spec(text: str | ChannelSpec, role: str) -> ChannelSpec:
    """Parse ``[NAME=]SOURCE[@N].FIELD[:UNIT]``; role is "input" or "output" (default names)."""
    if isinstance(text, ChannelSpec):
        return text
    m = _SPEC_RE.match(str(text))
    if m is None:
        raise DataError(
            f"bad {role} channel spec {text!r}: expected [NAME=]SOURCE[@N].FIELD[:UNIT], "
            "e.g. 'pitch_ref=vehicle_attitude_setpoint.pitch:rad' or 'ATTITUDE.pitch'"
        )
    fld = m["field"]
    unit = m["unit"].strip() if m["unit"] is not None else guess_unit(fld)
    return ChannelSpec(
        name=m["name"] or _default_name(fld, role),
        source=m["source"],
        instance=None if m["instance"] is None else int(m["instance"]),
        field=fld,
        unit=unit,
        text=str(text).strip(),
        unit_given=m["unit"] is not None,
    )


def check_names(inputs: Sequence[ChannelSpec], outputs: Sequence[ChannelSpec]) -> None:
    """Channel names must be unique across inputs and outputs (they key the dataset)."""
    if not inputs or not outputs:
        raise DataError(
            f"need at least one input and one output channel; got {len(inputs)} input(s) and "
            f"{len(outputs)} output(s) (use --preset or --input/--output)"
        )
    seen: dict[str, str] = {}
    for s in list(inputs) + list(outputs):
        if s.name in seen:
            raise DataError(
                f"channel name {s.name!r} is used twice ({seen[s.name]!r} and {s.text!r}); "
                "name one of them explicitly: NAME=SOURCE.FIELD"
            )
        seen[s.name] = s.text


def resolve_channels(
    preset: str | None,
    inputs: Sequence[str | ChannelSpec] | None,
    outputs: Sequence[str | ChannelSpec] | None,
    presets: dict[str, tuple[Sequence[str], Sequence[str]]],
    kind: str,
) -> tuple[list[ChannelSpec], list[ChannelSpec]]:
    """Preset channels (if any) followed by the explicit ones, parsed and checked."""
    pin: Sequence[str] = ()
    pout: Sequence[str] = ()
    if preset is not None:
        if preset not in presets:
            raise DataError(f"unknown {kind} preset {preset!r}; presets: {', '.join(sorted(presets))}")
        pin, pout = presets[preset]
    ins = [parse_channel_spec(s, "input") for s in list(pin) + list(inputs or [])]
    outs = [parse_channel_spec(s, "output") for s in list(pout) + list(outputs or [])]
    check_names(ins, outs)
    return ins, outs
