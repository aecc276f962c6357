"""Task engine for sweeps and fleet fits: a plain serial loop, or Ray tasks.

``workers=1`` runs every task in this process, in order (the debugging path the parallel results
are tested against). ``workers>1`` starts a local Ray runtime bound to 127.0.0.1 (nothing to start
by hand; shut down on exit); ``address=...`` connects to an existing Ray cluster instead (the
cluster is the user's: Ray's own launcher or KubeRay) and is left running.

What is shipped to a worker: the task function (pickled by reference: the package must be
installed on the cluster's nodes), one ``shared`` object put into Ray's object store once (numpy
arrays in it are read zero-copy by workers on the same node), and each task's small item. Results
come back through the object store as they finish; :meth:`Engine.imap_unordered` yields them with
their item index, so callers order them and the outcome does not depend on completion order.

Ray is optional (``pip install 'ddpc-codegen[cluster]'``) and imported only when a parallel engine
is asked for.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Sequence

from ddpc_codegen.errors import ConfigError

__all__ = ["Engine", "engine", "LOOPBACK"]

LOOPBACK = "127.0.0.1"


def _import_ray(local: bool) -> Any:
    """Import Ray; a local runtime is pinned to the loopback address before Ray reads its settings."""
    if local:
        # Ray resolves "127.0.0.1" to the machine's routable address unless clusters are disabled
        # (then every service binds to loopback only); usage statistics would try the network.
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    try:
        import ray
    except ModuleNotFoundError:
        raise ConfigError("--workers > 1 and --address need Ray: pip install 'ddpc-codegen[cluster]'") from None
    if local:
        from ray._private import ray_constants

        # Already imported earlier in this process (its constants were read then): same effect.
        ray_constants.ENABLE_RAY_CLUSTER = False
    return ray


class Engine:
    """Runs ``fn(shared, item)`` for every item, serially or as Ray tasks.

    Attributes:
        workers: parallel tasks at most (1 = serial in this process).
        address: the Ray cluster used, or None (serial / local runtime).
        memory_mib: memory asked for per task (Ray schedules no more tasks on a node than fit);
            None = no reservation.
    """

    def __init__(self, workers: int = 1, address: str | None = None, ray: Any = None,
                 memory_mib: float | None = None) -> None:
        self.workers = int(workers)
        self.address = address
        self.memory_mib = memory_mib
        self._ray = ray

    @property
    def parallel(self) -> bool:
        return self._ray is not None

    def imap_unordered(self, fn: Callable[[Any, Any], Any], items: Sequence[Any], shared: Any = None,
                       ) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, fn(shared, items[index]))`` as tasks finish (serial: in order).

        At most ``2 * workers`` tasks are in flight, so queued arguments and unread results in the
        object store stay bounded however many items there are.
        """
        if not self.parallel:
            for i, item in enumerate(items):
                yield i, fn(shared, item)
            return
        ray = self._ray
        # One retry of a task whose worker died (a force-cancelled task of an interrupted run may still take its
        # worker down under a new task; measured once in CI): a point is a pure function of its item, so a rerun
        # gives the same row. Exceptions raised by ``fn`` itself are not retried.
        opts: dict[str, Any] = {"num_cpus": 1, "max_retries": 1}
        if self.memory_mib:
            opts["memory"] = int(self.memory_mib * 2**20)
        task = ray.remote(**opts)(fn)
        shared_ref = ray.put(shared)
        pending: dict[Any, int] = {}
        nxt = 0
        try:
            while nxt < len(items) or pending:
                while nxt < len(items) and len(pending) < 2 * self.workers:
                    pending[task.remote(shared_ref, items[nxt])] = nxt
                    nxt += 1
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    yield pending.pop(ref), ray.get(ref)
        finally:
            for ref in pending:  # interrupted: do not leave tasks running for nothing
                ray.cancel(ref, force=True)


def _check_loopback(ray: Any) -> None:
    """Refuse a local runtime that is reachable from outside this machine."""
    addrs = {n.get("NodeManagerAddress") for n in ray.nodes()}
    if addrs != {LOOPBACK}:
        ray.shutdown()
        raise ConfigError(f"the local Ray runtime came up on {sorted(addrs)}, not {LOOPBACK}; refusing to use it")


@contextmanager
def engine(workers: int = 1, address: str | None = None, *, memory_mib: float | None = None,
           quiet: bool = False) -> Iterator[Engine]:
    """An :class:`Engine` for the duration of the ``with`` block.

    Args:
        workers: 1 = serial; N > 1 = a local Ray runtime with N CPUs (or N tasks at once on a cluster).
        address: an existing Ray cluster ("auto", "ray://host:10001", "host:6379"); None = local.
        memory_mib: per-task memory reservation (see :class:`Engine`).
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"--workers must be an integer >= 1; got {workers!r}")
    if workers == 1 and address is None:
        yield Engine(1, memory_mib=memory_mib)
        return
    local = address is None
    ray = _import_ray(local)
    started = False
    if not ray.is_initialized():
        kw: dict[str, Any] = dict(include_dashboard=False, log_to_driver=not quiet, logging_level="WARNING",
                                  configure_logging=True)
        if local:
            kw.update(address="local", num_cpus=workers, _node_ip_address=LOOPBACK)
        else:
            kw.update(address=address)
        if not quiet:
            print(f"starting Ray ({'local, 127.0.0.1' if local else address}, {workers} workers) ...",
                  file=sys.stderr, flush=True)
        ray.init(**kw)
        started = True
        if local:
            _check_loopback(ray)
    if address is not None and workers == 1:  # a cluster without --workers: as many tasks as it has CPUs
        workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
    try:
        yield Engine(workers, address, ray, memory_mib)
    finally:
        if started:
            ray.shutdown()
