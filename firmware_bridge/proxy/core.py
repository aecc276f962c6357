"""The transparent MAVLink proxy: several app / ground-station clients on one side, the vehicle on
the other, every byte forwarded unchanged both ways in arrival order.

- App side: one or more endpoints (:mod:`.app_side`). A UDP server (``udpin:HOST:PORT``, where apps
  and ground stations connect as to an autopilot's port): each distinct source address is a client
  from its first datagram on, however quiet afterwards (a bounded number; beyond it the one silent
  longest is replaced). A UDP client (``udpout:HOST:PORT``, as PX4 sends to an app listening on
  14540): that address is a client for as long as the proxy runs. A TCP server (``tcpin:HOST:PORT``):
  one client per connection.
- Vehicle side: one connection (:mod:`.vehicle_side`: ``udpin:`` -- the first sender is the vehicle,
  others are counted and dropped --, ``udpout:``, ``tcp:`` client with reconnects, or a serial device).
- Vehicle -> every client. Client -> vehicle. Client -> the other clients only with
  ``between_clients`` (off by default: each client then sees the vehicle as if it were alone on a
  direct link, which is what an autopilot's own UDP port gives it).
- Datagrams go out whole, as they came (garbage included: the receiver's parser copes as it would
  without the proxy). From a byte stream, each complete frame goes to the UDP clients as its own
  datagram; into a byte stream only whole frames are written (garbage cannot desync the stream).
- Frames are located and their checksums checked (:mod:`.frames`) to count them; only a candidate
  for rewriting is decoded, and only the rewrite hook (:mod:`.rewrite`) can change bytes.
- The bytes go out as soon as they are decided: counters, the sequence check, the app's setpoint period, the hook's
  own bookkeeping (:mod:`.rewrite`: ``settle``, a passive hook's call) and the vehicle's state come after the send.
"""

from __future__ import annotations

import select
import time
from typing import Any, Callable

from firmware_bridge.gc_pacer import GcPacer
from firmware_bridge.proxy.app_side import open_app_side
from firmware_bridge.proxy.frames import checksum_ok, frame_size, msgid, setpoint_target, splice, split_frames
from firmware_bridge.proxy.rewrite import SETPOINT_MSGIDS, SetpointRewrite, decode_setpoint, has_position
from firmware_bridge.proxy.stats import DirectionStats, SetpointPeriod
from firmware_bridge.proxy.vehicle_side import VehicleSide
from firmware_bridge.proxy.vehicle_view import VIEW_MSGIDS, VehicleView

__all__ = ["Proxy"]

_POLL_S = 0.1  # housekeeping period: reconnects, the setpoint role's release, the stop check


class Proxy:
    """A transparent MAVLink proxy (see the module docstring).

    Args:
        apps: the app side: ``udpin:``/``udpout:``/``tcpin:HOST:PORT`` strings (or one string).
        vehicle: the vehicle side (``udpin:``/``udpout:``/``tcp:`` or a serial device).
        rewrite: the setpoint hook; None: pass-through.
        view: the vehicle's state the hook reads, folded in from the vehicle's heartbeats and positions.
        baud: a serial vehicle's baud rate (default from the string, else 921600).
        between_clients: also forward each client's datagrams to the other clients.
        client_timeout: the app's client silent this long [s] is no longer the app (the next client to send a
            setpoint is: a restarted app on a new port); a ``udpin`` vehicle silent this long is replaced by the
            next sender (a restarted autopilot). Clients themselves stay (see :mod:`.app_side`).
        reconnect_interval: seconds between attempts to reopen a failed vehicle link.
    """

    def __init__(self, apps: str | list[str], vehicle: str, *, rewrite: SetpointRewrite | None = None,
                 view: VehicleView | None = None,
                 baud: int | None = None, between_clients: bool = False, client_timeout: float = 5.0,
                 reconnect_interval: float = 1.0, ring_size: int = 1 << 16) -> None:
        self.app_urls, self.vehicle_url = [apps] if isinstance(apps, str) else list(apps), vehicle
        self.apps = [open_app_side(u) for u in self.app_urls]
        self.vehicle = VehicleSide(vehicle, baud, reconnect_interval, repin_after=client_timeout)
        self.rewrite, self.view = rewrite, view
        self.between_clients = between_clients
        self.pacer = GcPacer()  # started by the command, its process's one loop: collect after a setpoint's send
        self.client_timeout = client_timeout
        # (app endpoint index, address) -> [last heard (monotonic), datagrams in, datagrams out]
        self.clients: dict[tuple[int, Any], list] = {}
        self.setpoint_client: Any = None  # the client whose setpoints are the app's (first to send one)
        self.setpoints = SetpointPeriod()
        self.up, self.down = DirectionStats(ring_size), DirectionStats(ring_size)  # app -> vehicle, vehicle -> apps
        self.events = dict.fromkeys(("clients_joined", "clients_left", "foreign_setpoints",
                                     "rewrite_errors", "between_clients", "own_messages"), 0)
        self._poll = select.poll()
        self._fds: dict[int, int] = {}  # polled descriptor -> app endpoint index (-1: the vehicle)
        self._t0 = time.monotonic()
        self._membership()

    # ------------------------------------------------------------------ the loop
    def run(self, duration: float | None = None, stop: Callable[[], bool] = lambda: False) -> None:
        """Forward until ``stop()`` is true or ``duration`` seconds have passed; what had arrived by then
        is still forwarded (a stop loses nothing that was received)."""
        end = None if duration is None else time.monotonic() + duration
        while not stop():
            now = time.monotonic()
            if end is not None and now >= end:
                break
            self.vehicle.maintain(now)
            self._own(now)
            self._watch_fds()
            self._forward(_POLL_S)
            self._membership()
            self._release_setpoints(time.monotonic())
        self._forward(0.0)

    def _own(self, now: float) -> None:
        """The proxy's own messages (the steering's stream request), written between forwarded ones."""
        own = getattr(self.rewrite, "own_messages", None)
        if own is not None and self.vehicle.ready:
            for frame in own(time.time()):
                if self.vehicle.write(frame):
                    self.events["own_messages"] += 1

    def _forward(self, timeout: float) -> None:
        """Wait up to ``timeout`` [s] for input and forward everything pending."""
        for fd, _ev in self._poll.poll(timeout * 1000):
            k = self._fds.get(fd)
            if k is None:
                continue
            if k < 0:
                for chunk in self.vehicle.read():
                    self._from_vehicle(*chunk)
                continue
            got = self.apps[k].read(fd)
            if self.apps[k].joined or self.apps[k].gone:  # a new client hears the vehicle from now on
                self._membership()
            for addr, data, t_rx in got:
                self._from_client((k, addr), data, t_rx)

    def _watch_fds(self) -> None:
        """Poll exactly the descriptors the endpoints have now (a reopened vehicle, TCP connections)."""
        want = {fd: k for k, a in enumerate(self.apps) for fd in a.fds()}
        vfd = self.vehicle.fileno()
        if vfd is not None:
            want[vfd] = -1
        if want != self._fds:
            for fd in self._fds.keys() - want.keys():
                self._poll.unregister(fd)
            for fd in want.keys() - self._fds.keys():
                self._poll.register(fd, select.POLLIN)
            self._fds = want

    def _membership(self) -> None:
        """Clients that an endpoint added (a udpout app, a UDP sender, a TCP connection) or dropped."""
        for k, a in enumerate(self.apps):
            for addr in a.joined:
                if (k, addr) not in self.clients:
                    self.clients[(k, addr)] = [time.monotonic(), 0, 0]
                    self.events["clients_joined"] += 1
            for addr in a.gone:
                self._forget((k, addr), "clients_left")
            a.joined.clear()
            a.gone.clear()

    def _release_setpoints(self, now: float) -> None:
        """The app that has been silent ``client_timeout`` is no longer the app (its client stays)."""
        c = self.clients.get(self.setpoint_client)
        if c is not None and now - c[0] > self.client_timeout:
            self._keep(self.setpoint_client, False)

    def _keep(self, client: tuple[int, Any] | None, app: bool) -> None:
        """``client`` becomes the app (``app``) or stops being it; while it is, its UDP endpoint never replaces it
        with a new sender, so a flood from many ports cannot take its place."""
        if client is not None:
            kept = getattr(self.apps[client[0]], "kept", None)
            if kept is not None:
                (kept.add if app else kept.discard)(client[1])
        self.setpoint_client = client if app else None

    def _forget(self, client: tuple[int, Any], why: str) -> None:
        if self.clients.pop(client, None) is not None:
            self.events[why] += 1
        if client == self.setpoint_client:
            self._keep(client, False)

    # ------------------------------------------------------------------ app -> vehicle
    def _from_client(self, client: tuple[int, Any], data: bytes, t_rx: float) -> None:
        """Forward one datagram (or a stream's frames) of ``client``: the bytes go out as soon as they are decided
        (the hook's replacements); counting, the sequence check and the hook's bookkeeping come after the send."""
        spans, garbage, _ = split_frames(data)
        replaced: dict[int, bytes] = {}
        later: list[tuple[bytes, Any]] = []  # the setpoints (frame, decoded or None) whose hook work comes after
        for i, n in spans:
            if msgid(data, i) in SETPOINT_MSGIDS:
                r = self._setpoint(client, data[i:i + n], t_rx, later)
                if r is not None:
                    replaced[i] = r
        if self.vehicle.datagram:
            out = splice(data, spans, replaced)
        elif garbage or replaced:  # into a byte stream only whole frames
            out = b"".join(replaced.get(i) or data[i:i + n] for i, n in spans)
        else:
            out = data
        sent = bool(out) and self.vehicle.write(out)
        if sent:
            self.up.latency.add(time.time() - t_rx)
        self._after_client(client, data, spans, garbage, len(replaced), sent, bool(out), t_rx, later)

    def _after_client(self, client: tuple[int, Any], data: bytes, spans: list[tuple[int, int]], garbage: int,
                      rewritten: int, sent: bool, nonempty: bool, t_rx: float, later: list) -> None:
        """What a datagram of ``client`` leaves to do once it is out: counters, the sequence check, the app's
        setpoint period, the hook's settling, and the other clients' copies (``between_clients``)."""
        st = self.up.c
        st["datagrams"] += 1
        c = self.clients.get(client)
        if c is not None:  # (None: a UDP sender replaced within the same read; its datagram still went out)
            c[0] = time.monotonic()
            c[1] += 1
        st["received"] += len(spans)
        st["garbage_bytes"] += garbage
        st["rewritten"] += rewritten
        see = self.up.see
        for i, _n in spans:
            see(data, i)
        if sent:
            st["forwarded"] += len(spans)
        else:
            st["dropped"] += len(spans)
            if nonempty and self.vehicle.ready:  # not merely "the vehicle is not heard yet"
                st["send_errors"] += 1
        for _ in later:
            self.setpoints.add(t_rx)
        for frame, msg in later:
            self._settle(frame, msg, t_rx)
        if later:
            self.pacer.idle(time.monotonic())
        if self.between_clients:
            clean = data if not garbage else b"".join(data[i:i + n] for i, n in spans)
            for a in list(self.clients):
                if a != client and self._to_client(a, data, clean):
                    self.events["between_clients"] += 1

    def _setpoint(self, client: tuple[int, Any], frame: bytes, t_rx: float, later: list) -> bytes | None:
        """The frame to send instead of the setpoint ``frame``, or None; the setpoint is noted in ``later`` when it
        is the app's (its hook work after the send: a passive hook's whole call, a settling hook's settle)."""
        sysid = None if self.view is None else self.view.sysid
        if sysid is not None and setpoint_target(frame, 0) not in (0, sysid):
            self.events["foreign_setpoints"] += 1  # addressed to another vehicle: never the app's
            return None
        if self.setpoint_client is None:
            self._keep(client, True)
        if client != self.setpoint_client:
            self.events["foreign_setpoints"] += 1  # not the app's: never steered
            return None
        hook = self.rewrite
        if hook is None or getattr(hook, "passive", False):  # (a passive hook never replaces: it runs after)
            later.append((frame, None))
            return None
        msg = decode_setpoint(frame)
        if msg is None or not has_position(msg):
            later.append((frame, False))
            return None
        decide = getattr(hook, "decide", None)
        later.append((frame, msg if decide is not None else False))
        try:
            r = (decide or hook)(msg, frame, t_rx)
        except Exception:  # any fault of the hook: the app's own setpoint goes out
            self.events["rewrite_errors"] += 1
            return None
        if r is None:
            return None
        r = bytes(r)
        n = len(r)  # one whole frame, its checksum valid, of the same message:
        if not n or frame_size(r, 0) != n or not checksum_ok(r, 0, n) or msgid(r, 0) != msgid(frame, 0):
            self.events["rewrite_errors"] += 1
            return None
        return r

    def _settle(self, frame: bytes, msg: Any, t_rx: float) -> None:
        """The hook's work on the app's setpoint ``frame`` after the send: a passive hook's call (``msg`` None: its
        answer is never a replacement), a settling hook's ``settle()`` (``msg`` decoded); False: nothing."""
        hook = self.rewrite
        if hook is None or msg is False:
            return
        try:
            if msg is None:
                m = decode_setpoint(frame)
                if m is not None and has_position(m):
                    hook(m, frame, t_rx)
            else:
                hook.settle()
        except Exception:  # the setpoint is out: a fault here is counted, the next one is decided anew
            self.events["rewrite_errors"] += 1

    # ------------------------------------------------------------------ vehicle -> apps
    def _from_vehicle(self, outs: list[tuple[bytes, int]], spans: list[tuple[int, int]], buf: bytes, garbage: int,
                      t_rx: float) -> None:
        st = self.down.c
        lat = self.down.latency
        for out, frames in outs:
            if not self.clients:
                st["dropped"] += frames
                continue
            # a stream client gets whole frames only (a stream vehicle's outs are single frames already)
            clean = out if not garbage or len(outs) > 1 else b"".join(buf[i:i + n] for i, n in spans)
            for a in list(self.clients):
                if self._to_client(a, out, clean):
                    st["forwarded"] += frames
                    lat.add(time.time() - t_rx)
                else:
                    st["dropped"] += frames
                    st["send_errors"] += 1
        # after the sends (the view is read by the hook on the next setpoint, which comes after this returns)
        st["datagrams"] += 1
        st["received"] += len(spans)
        st["garbage_bytes"] += garbage
        view = self.view
        for i, n in spans:
            self.down.see(buf, i)
            if view is not None and msgid(buf, i) in VIEW_MSGIDS:
                view.on_frame(buf[i:i + n], t_rx)

    def _to_client(self, client: tuple[int, Any], buf: bytes, frames: bytes) -> bool:
        if not self.apps[client[0]].send(client[1], buf, frames):
            return False
        c = self.clients.get(client)
        if c is not None:  # (a TCP client whose send failed is gone)
            c[2] += 1
        return True

    # ------------------------------------------------------------------ results
    def summary(self) -> dict:
        """The counters, latencies [us] and the app's setpoint period, JSON-ready."""
        up = self.up.summary()
        up["garbage_bytes"] += sum(a.garbage for a in self.apps)  # what TCP clients sent between frames
        return {
            "apps": self.app_urls, "vehicle": self.vehicle_url, "uptime_s": time.monotonic() - self._t0,
            "vehicle_peer": list(self.vehicle.peer) if self.vehicle.peer else None,
            "between_clients": self.between_clients, "rewrite_hook": self.rewrite is not None,
            "app_to_vehicle": up, "vehicle_to_app": self.down.summary(),
            "setpoints": {**self.setpoints.summary(),
                          "client": self._client_json(self.setpoint_client)},
            "clients": [{**self._client_json(a), "datagrams_in": c[1], "datagrams_out": c[2],
                         "silent_s": time.monotonic() - c[0]} for a, c in self.clients.items()],
            "events": {**self.events, **{f"vehicle_{k}": v for k, v in self.vehicle.counts.items()}},
            "last_vehicle_error": self.vehicle.last_error,
        }

    def _client_json(self, client: tuple[int, Any] | None) -> dict | None:
        return None if client is None else {"app": self.app_urls[client[0]], "address": list(client[1])}

    def close(self) -> None:
        for a in self.apps:
            a.close()
        self.vehicle.close()


