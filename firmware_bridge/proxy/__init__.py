"""The steering proxy's foundation: a transparent MAVLink proxy between a user's own app (and
ground stations) and the vehicle, with counters, added-latency statistics and a setpoint rewrite
hook (pass-through by default). See docs/guides/proxy.md."""

from firmware_bridge.proxy.core import Proxy
from firmware_bridge.proxy.rewrite import PROXY_COMPONENT, SetpointEncoder, SetpointRewrite

__all__ = ["Proxy", "SetpointRewrite", "SetpointEncoder", "PROXY_COMPONENT"]
