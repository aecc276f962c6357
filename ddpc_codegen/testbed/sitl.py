"""Start and stop real autopilot SITLs (ArduCopter, PX4 with SIH) for tests and demos.

The binaries are not part of the project; they are found through two environment variables:

* ``DDPC_ARDUPILOT_SITL``: the ``arducopter`` binary (``copter.parm`` next to it is used as the
  default parameter file);
* ``DDPC_PX4_SITL``: the folder holding ``bin/px4`` and ``etc/``.

Every SITL runs from a fresh temporary working directory (both write parameters, logs and
storage there) and talks on loopback only. Run it inside a private network namespace when
possible, so that parallel runs cannot collide on the fixed ports: :func:`run_isolated` re-runs a
Python function under ``unshare -n`` (root) or ``unshare -rn`` (an unprivileged user namespace),
and the SITL and its client then share that namespace. Without a private namespace,
:class:`Sitl` takes an ``instance`` number that moves every port (ArduPilot ``-I``, PX4 ``-i``).
PX4 also holds a server socket per instance in /tmp (``/tmp/px4-sock-N``), which namespaces do not
separate: :meth:`Sitl.px4` takes the first instance nobody serves (:func:`free_px4_instance`).

Example::

    with Sitl.ardupilot(find_ardupilot(), params={"GUID_OPTIONS": 8}) as sitl:
        conn = sitl.connect()          # pymavlink connection, heartbeat already seen
        ...

Measured start-up (2-core machine): first heartbeat after 1-2 s on both; ArduCopter sends
LOCAL_POSITION_NED only once its EKF uses GPS (~42 s after start), PX4 SIH from the start and
accepts arming ~4 s after start. Both exit within 10 ms of SIGTERM.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

__all__ = [
    "ARDUPILOT_ENV",
    "PX4_ENV",
    "SitlError",
    "Sitl",
    "find_ardupilot",
    "find_px4",
    "netns_command",
    "in_private_netns",
    "run_isolated",
    "missing_reason",
    "make_sitl",
    "free_px4_instance",
]

ARDUPILOT_ENV = "DDPC_ARDUPILOT_SITL"
PX4_ENV = "DDPC_PX4_SITL"
_PARENT_NETNS_ENV = "DDPC_PARENT_NETNS"
_HOME = "-35.363261,149.165230,584,353"  # ArduPilot's autotest home (CMAC), as its docs use
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12


class SitlError(RuntimeError):
    """A SITL could not be started, did not answer, or is not installed."""


# ----------------------------------------------------------------------------- discovery
def find_ardupilot(env: Mapping[str, str] | None = None) -> Path | None:
    """The ArduCopter SITL binary named by ``DDPC_ARDUPILOT_SITL`` (None if unset or missing)."""
    v = (env if env is not None else os.environ).get(ARDUPILOT_ENV, "")
    p = Path(v) if v else None
    return p if p is not None and p.is_file() and os.access(p, os.X_OK) else None


def find_px4(env: Mapping[str, str] | None = None) -> Path | None:
    """The PX4 SITL folder (``bin/px4`` + ``etc/``) named by ``DDPC_PX4_SITL`` (None if absent)."""
    v = (env if env is not None else os.environ).get(PX4_ENV, "")
    p = Path(v) if v else None
    if p is None or not (p / "bin" / "px4").is_file() or not (p / "etc").is_dir():
        return None
    return p


# ----------------------------------------------------------------------------- namespaces
def _netns_id() -> str:
    try:
        return os.readlink("/proc/self/ns/net")
    except OSError:
        return ""


def in_private_netns() -> bool:
    """True when this process runs in a network namespace made for it by :func:`run_isolated`
    (its namespace differs from the one its launcher recorded)."""
    parent = os.environ.get(_PARENT_NETNS_ENV, "")
    return bool(parent) and parent != _netns_id()


def netns_command() -> list[str] | None:
    """The ``unshare`` prefix that gives a command a private network namespace with loopback up,
    or None when this machine does not allow it (no ``unshare``, or neither root nor
    unprivileged user namespaces). Root: ``unshare -n``; otherwise ``unshare -rn`` (a user
    namespace in which the caller is root, which is what creating a network namespace needs)."""
    unshare, ip = shutil.which("unshare"), shutil.which("ip") or "/usr/sbin/ip"
    if unshare is None or not Path(ip).exists():
        return None
    for flags in (["-n"], ["-rn"]) if os.geteuid() == 0 else (["-rn"],):
        probe = [unshare, *flags, ip, "link", "set", "lo", "up"]
        try:
            ok = subprocess.run(probe, capture_output=True, timeout=10).returncode == 0
        except (OSError, subprocess.TimeoutExpired):
            ok = False
        if ok:
            return [unshare, *flags, "sh", "-c", f'{ip} link set lo up && exec "$@"', "netns"]
    return None


def run_isolated(func: str, kwargs: Mapping[str, Any], *, timeout: float,
                 python: str | None = None, cwd: str | Path | None = None) -> dict:
    """Run ``module:function(**kwargs)`` in a child Python inside a private network namespace and
    return its JSON-serialisable result.

    The child is started as ``unshare -n python -c ...`` (see :func:`netns_command`); without a
    namespace available it runs on the shared loopback (the caller then uses distinct
    ``instance`` numbers). The child's process group is killed when ``timeout`` [s] passes. What
    the child prints goes to this process's stdout as it runs (progress of long runs).

    Raises:
        SitlError: the child failed, timed out or returned no result (its stderr tail attached).
    """
    prefix = netns_command() or []
    with tempfile.TemporaryDirectory(prefix="ddpc-isolated-") as tmp:
        out = Path(tmp) / "result.json"
        code = ("import json, importlib, sys\n"
                "mod, _, fn = sys.argv[1].partition(':')\n"
                "res = getattr(importlib.import_module(mod), fn)(**json.loads(sys.argv[2]))\n"
                "open(sys.argv[3], 'w').write(json.dumps(res))\n")
        cmd = [*prefix, python or sys.executable, "-c", code, func, json.dumps(dict(kwargs)), str(out)]
        # The child sees this process's import path (pytest's rootdir / pythonpath entries included).
        path = os.pathsep.join(p for p in sys.path if p)
        env = {**os.environ, _PARENT_NETNS_ENV: _netns_id() if prefix else "", "PYTHONPATH": path}
        # stdout passes through (the child's progress lines, live); stderr is kept for the error message.
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=None, stderr=subprocess.PIPE, start_new_session=True)
        try:
            _, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            _kill_group(proc, grace=2.0)
            _, err = proc.communicate()
            raise SitlError(f"{func} did not finish within {timeout:g} s; stderr tail:\n{_tail(err)}") from None
        if proc.returncode != 0 or not out.exists():
            raise SitlError(f"{func} failed (exit {proc.returncode}); stderr tail:\n{_tail(err)}")
        return json.loads(out.read_text())


def _tail(b: bytes | None, n: int = 2000) -> str:
    return (b or b"").decode(errors="replace")[-n:]


def _kill_group(proc: subprocess.Popen, grace: float) -> None:
    """SIGTERM the process group led by ``proc``, SIGKILL it after ``grace`` seconds."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=grace)
            return
        except subprocess.TimeoutExpired:
            continue


def _px4_bin(src: Path, dst: Path) -> None:
    """Link PX4's ``bin`` folder into ``dst``: ``px4`` and ``px4-alias.sh`` to the originals, every
    ``px4-<module>`` command to ``px4`` (what PX4's build makes; a copy made without preserving
    symlinks has 3-byte text files "px4" there instead, which the start-up script cannot run)."""
    dst.mkdir()
    for f in src.iterdir():
        if f.name == "px4" or not f.name.startswith("px4-") or f.name.endswith(".sh"):
            (dst / f.name).symlink_to(f.resolve())
        else:
            (dst / f.name).symlink_to("px4")


# ----------------------------------------------------------------------------- the SITL process
@dataclass
class Sitl:
    """One SITL process (use :meth:`ardupilot` / :meth:`px4`, then as a context manager).

    Attributes:
        autopilot: "ardupilot" or "px4".
        argv: the command line; env: extra environment; url: where a client connects
            (pymavlink syntax); expected_autopilot: HEARTBEAT.autopilot of this SITL.
        workdir: fresh temporary working directory (removed at :meth:`stop` unless ``keep``).
        startup_timeout: seconds to wait for the first heartbeat.
        sysid: the autopilot's MAVLink system id (PX4 instance N answers as N + 1).
    """

    autopilot: str
    argv: list[str]
    url: str
    expected_autopilot: int
    env: dict[str, str] = field(default_factory=dict)
    files: dict[str, str] = field(default_factory=dict)
    startup_timeout: float = 60.0
    keep: bool = False
    workdir: Path | None = None
    proc: subprocess.Popen | None = None
    started_at: float = float("nan")
    px4_bin: Path | None = None
    sysid: int = 1  # the autopilot's MAVLink system id (PX4: instance + 1, set by its rcS)

    # ---------------------------------------------------------------- constructors
    @classmethod
    def ardupilot(cls, binary: str | Path, *, params: Mapping[str, float] | None = None,
                  instance: int = 0, defaults: str | Path | None = None, speedup: float = 1.0) -> "Sitl":
        """ArduCopter SITL, quad "+" frame, real time; TCP server on ``5760 + 10 * instance``.

        Args:
            binary: the ``arducopter`` executable.
            params: extra parameters, written to ``extra.parm`` and appended to ``--defaults``.
            defaults: the base parameter file (default: ``copter.parm`` beside the binary).
        """
        binary = Path(binary).resolve()
        base = Path(defaults) if defaults else binary.parent / "copter.parm"
        if not base.is_file():
            raise SitlError(f"ArduPilot default parameter file {base} not found")
        files = {}
        parm = str(base)
        if params:
            files["extra.parm"] = "".join(f"{k} {float(v):g}\n" for k, v in params.items())
            parm += ",extra.parm"
        argv = [str(binary), "--model", "+", "--speedup", f"{speedup:g}", f"-I{int(instance)}", "-w",
                "--sim-address=127.0.0.1", "--defaults", parm, "--home", _HOME]
        return cls("ardupilot", argv, f"tcp:127.0.0.1:{5760 + 10 * int(instance)}",
                   MAV_AUTOPILOT_ARDUPILOTMEGA, files=files)

    @classmethod
    def px4(cls, folder: str | Path, *, params: Mapping[str, float] | None = None, instance: int | None = None,
            model: str = "sihsim_quadx") -> "Sitl":
        """PX4 SITL with SIH; its off-board link sends to UDP ``14540 + instance`` on 127.0.0.1.

        Args:
            folder: holds ``bin/px4`` and ``etc/``.
            params: parameters set at start through PX4's ``PX4_PARAM_<NAME>`` environment hook
                (applied by ``rcS`` after the airframe defaults, before the modules start).
            instance: PX4's instance number (None: the first free one, :func:`free_px4_instance`).
                PX4 holds a server socket per instance in /tmp, which network namespaces do not
                separate: a second PX4 of the same instance says "PX4 server already running" and exits.
        """
        folder = Path(folder).resolve()
        instance = free_px4_instance() if instance is None else int(instance)
        # bin/px4 runs from a link farm in the working directory: PX4 puts its own folder on PATH
        # for the start-up script's px4-<module> commands, and a copied build may have lost those
        # symlinks (see :func:`_px4_bin`).
        argv = ["{workdir}/bin/px4", "-d", str(folder / "etc"), "-w", "{workdir}"]
        if instance:
            argv += ["-i", str(int(instance))]
        env = {"PX4_SIM_MODEL": model, "PX4_SIMULATOR": "sihsim"}
        env.update({f"PX4_PARAM_{k}": f"{v:g}" if isinstance(v, float) else str(v) for k, v in (params or {}).items()})
        return cls("px4", argv, f"udpin:127.0.0.1:{14540 + int(instance)}", MAV_AUTOPILOT_PX4, env=env,
                   px4_bin=folder / "bin", sysid=int(instance) + 1)

    # ---------------------------------------------------------------- life cycle
    def start(self) -> "Sitl":
        """Create the working directory and start the process (own session: stopped as a group)."""
        if self.proc is not None:
            raise SitlError("already started")
        self.workdir = Path(tempfile.mkdtemp(prefix=f"ddpc-sitl-{self.autopilot}-"))
        for name, text in self.files.items():
            (self.workdir / name).write_text(text)
        if self.px4_bin is not None:
            _px4_bin(self.px4_bin, self.workdir / "bin")
        argv = [a.replace("{workdir}", str(self.workdir)) for a in self.argv]
        log = open(self.workdir / "sitl.log", "wb")
        try:
            self.proc = subprocess.Popen(argv, cwd=self.workdir, env={**os.environ, **self.env},
                                         stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                         start_new_session=True)
        except OSError as e:
            raise SitlError(f"cannot start {argv[0]}: {e}") from e
        finally:
            log.close()
        self.started_at = time.monotonic()
        return self

    def connect(self, timeout: float | None = None, source_system: int = 255, **kw: Any):
        """A pymavlink connection to the SITL once its heartbeat arrives.

        Returns:
            ``mavutil`` connection whose ``target_system`` / ``target_component`` are the autopilot's.

        Raises:
            SitlError: no heartbeat within ``timeout`` [s] (default ``startup_timeout``), the process
                died, or the heartbeat names another autopilot than expected.
        """
        from pymavlink import mavutil

        t_end = time.monotonic() + (self.startup_timeout if timeout is None else timeout)
        conn = None
        while time.monotonic() < t_end:
            self._check_alive()
            if conn is None and not self._port_ready():
                time.sleep(0.2)
                continue
            conn = conn or mavutil.mavlink_connection(self.url, source_system=source_system,
                                                      autoreconnect=False, **kw)
            hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            if hb is not None and hb.autopilot != 8:  # MAV_AUTOPILOT_INVALID: a GCS or companion
                if hb.autopilot != self.expected_autopilot:
                    raise SitlError(f"{self.autopilot} SITL heartbeat names autopilot {hb.autopilot}")
                conn.target_system, conn.target_component = hb.get_srcSystem(), hb.get_srcComponent()
                return conn
        if conn is not None:
            conn.close()
        raise SitlError(f"no heartbeat from the {self.autopilot} SITL on {self.url} within the timeout; "
                        f"log tail:\n{self.log_tail()}")

    def set_params(self, params: Mapping[str, float], timeout: float = 15.0) -> dict[str, float]:
        """Set parameters on the running SITL over MAVLink (PARAM_SET, repeated until the echoed
        PARAM_VALUE carries the value), e.g. between two flights; call it while no other client holds
        the SITL's port (a bridge process is done). Float parameters only (PX4 packs integers bytewise).

        Returns:
            name -> the value the SITL echoed.
        Raises:
            SitlError: a parameter was not confirmed within ``timeout`` [s] (unknown name, or no answer).
        """
        if not params:
            return {}
        conn = self.connect()
        got: dict[str, float] = {}
        try:
            t_end = time.monotonic() + timeout
            next_send = 0.0
            while len(got) < len(params) and time.monotonic() < t_end:
                if time.monotonic() >= next_send:
                    next_send = time.monotonic() + 1.0
                    for name, value in params.items():
                        if name not in got:
                            conn.mav.param_set_send(conn.target_system, conn.target_component, name.encode(),
                                                    float(value), 9)  # MAV_PARAM_TYPE_REAL32
                msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
                if msg is None:
                    continue
                name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="ignore")
                name = name.rstrip("\x00")
                if name in params and abs(float(msg.param_value) - float(params[name])) <= 1e-4 * max(1.0, abs(params[name])):
                    got[name] = float(msg.param_value)
        finally:
            conn.close()
        missing = sorted(set(params) - set(got))
        if missing:
            raise SitlError(f"the {self.autopilot} SITL did not confirm {missing} within {timeout:g} s "
                            "(unknown parameter, or no answer)")
        return got

    def _port_ready(self) -> bool:
        """TCP: the SITL's server accepts connections (probed here because pymavlink prints and
        sleeps on a refused connect). UDP listeners are always ready."""
        if not self.url.startswith("tcp:"):
            return True
        host, _, port = self.url[4:].rpartition(":")
        try:
            socket.create_connection((host, int(port)), timeout=0.5).close()
        except OSError:
            return False
        return True

    def _check_alive(self) -> None:
        if self.proc is None:
            raise SitlError("not started")
        if self.proc.poll() is not None:
            raise SitlError(f"{self.autopilot} SITL exited with {self.proc.returncode}; log tail:\n{self.log_tail()}")

    def log_tail(self, n: int = 2000) -> str:
        """The end of the SITL's console output."""
        p = self.workdir / "sitl.log" if self.workdir else None
        return p.read_bytes()[-n:].decode(errors="replace") if p and p.exists() else ""

    def stop(self, grace: float = 5.0) -> int | None:
        """SIGTERM the SITL's process group, SIGKILL after ``grace`` seconds; remove the working
        directory. Returns the exit code (None if it was never started)."""
        rc = None
        if self.proc is not None:
            if self.proc.poll() is None:
                _kill_group(self.proc, grace)
            rc = self.proc.wait()
            self.proc = None
        if self.workdir is not None and not self.keep:
            shutil.rmtree(self.workdir, ignore_errors=True)
            self.workdir = None
        return rc

    def __enter__(self) -> "Sitl":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


PX4_SOCKET = "/tmp/px4-sock-{}"  # the PX4 daemon's server socket per instance (shared by every netns)


def free_px4_instance(limit: int = 16, socket_path: str = PX4_SOCKET) -> int:
    """The lowest PX4 instance number whose server socket nobody serves (absent, or left by a dead
    PX4: a connection is refused).

    Raises:
        SitlError: all of 0 .. limit-1 are taken.
    """
    for i in range(limit):
        path = socket_path.format(i)
        if not os.path.exists(path):
            return i
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            try:
                s.connect(path)
            except OSError:
                return i  # stale: its PX4 is gone
    raise SitlError(f"every PX4 instance 0..{limit - 1} is running on this machine ({socket_path.format('N')})")


def missing_reason(autopilot: str) -> str | None:
    """Why the SITL of ``autopilot`` ("ardupilot" or "px4") cannot run here, or None if it can."""
    if autopilot == "ardupilot":
        return None if find_ardupilot() else (
            f"ArduCopter SITL not found: set {ARDUPILOT_ENV} to the arducopter binary (see the README)")
    if autopilot == "px4":
        return None if find_px4() else (
            f"PX4 SITL not found: set {PX4_ENV} to the folder holding bin/px4 and etc/ (see the README)")
    raise ValueError(f"unknown autopilot {autopilot!r}; choose 'ardupilot' or 'px4'")


def make_sitl(autopilot: str, **kw: Any) -> Sitl:
    """The installed SITL of ``autopilot`` (keywords as :meth:`Sitl.ardupilot` / :meth:`Sitl.px4`).

    Raises:
        SitlError: it is not installed (the message says which variable to set).
    """
    why = missing_reason(autopilot)
    if why:
        raise SitlError(why)
    if autopilot == "ardupilot":
        return Sitl.ardupilot(find_ardupilot(), **kw)
    return Sitl.px4(find_px4(), **kw)
