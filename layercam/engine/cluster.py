"""Tasks on a Ray cluster (``--ray auto|ADDRESS``): a long clip's windows and ``layercam batch``'s jobs.

Ray is an optional dependency (``pip install 'layercam[ray]'``); without ``--ray`` nothing here is
imported and the work runs in sequence in this process, as it always did.

* ``--ray auto``: the Ray cluster this machine belongs to (``RAY_ADDRESS``, or one started with
  ``ray start``), else a Ray instance started here for this command, on this machine's CPUs (and
  GPUs); a Ray instance already started in this process (``ray.init``) is used as it is.
* ``--ray ADDRESS``: that cluster (``HOST:6379``, or ``ray://HOST:10001`` through Ray Client).

Each task asks for one GPU when the cluster has one, else for one CPU (and trains with one torch
thread). Tasks read their inputs and write their results at the same paths as this command: the
run folders (and a batch's clips) must be reachable at those paths from every node of the cluster
(a shared file system; on one machine they are). Results are gathered into the one run folder.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator

from layercam.core.errors import LayercamError

__all__ = ["available", "connect", "Runner"]

INSTALL = "pip install 'layercam[ray]'"


def _ray():
    try:
        import ray
    except ImportError:
        raise LayercamError(f"--ray needs Ray, which is not installed here: {INSTALL} (or run "
                            "without --ray, in sequence)") from None
    return ray


def available() -> None:
    """Refuses (one line) ``--ray`` where Ray is not installed: said before any work."""
    _ray()


def connect(address: str):
    """The ``ray`` module, connected to the cluster ``address`` names (module docstring)."""
    ray = _ray()
    if ray.is_initialized():
        return ray
    kw = {"logging_level": logging.WARNING, "include_dashboard": False}
    try:
        if address == "auto":
            try:
                ray.init(address="auto", **kw)
            except ConnectionError:  # no cluster running: one on this machine, for this command
                ray.init(**kw)
        else:
            ray.init(address=address, **kw)
    except LayercamError:
        raise
    except Exception as e:  # noqa: BLE001 - any failure to reach the cluster is one line
        first = (str(e).strip().splitlines() or [e.__class__.__name__])[0]
        raise LayercamError(f"--ray {address}: cannot connect to a Ray cluster ({first[:200]})") from None
    return ray


class Runner:
    """Runs a function over items as Ray tasks, one task per item: one GPU each when the cluster
    has GPUs, else one CPU (``threads`` 1: the torch threads a CPU task trains with)."""

    def __init__(self, address: str, say: Callable[[str], None] = print):
        self.ray = connect(address)
        res = self.ray.cluster_resources()
        gpus, cpus = int(res.get("GPU", 0)), int(res.get("CPU", 0))
        self.options = {"num_gpus": 1} if gpus >= 1 else {"num_cpus": 1}
        self.threads = 0 if gpus >= 1 else 1
        self.describe = f"cluster of {cpus} CPUs and {gpus} GPUs: one task per {'GPU' if gpus else 'CPU'}"
        say(f"[ray] {self.describe}")

    def as_completed(self, fn, items: list) -> Iterator[tuple[int, object]]:
        """``(i, fn(items[i]))`` in the order the tasks finish. A task's ``LayercamError`` is
        raised here as it was raised there; Ctrl-C cancels the tasks not yet finished."""
        from ray.exceptions import RayTaskError

        remote = self.ray.remote(**self.options)(fn)
        refs = [remote.remote(x) for x in items]
        where = {r: i for i, r in enumerate(refs)}
        pending = list(refs)
        try:
            while pending:
                done, pending = self.ray.wait(pending, num_returns=1)
                try:
                    yield where[done[0]], self.ray.get(done[0])
                except RayTaskError as e:
                    cause = getattr(e, "cause", None)
                    if isinstance(cause, (LayercamError, KeyboardInterrupt)):
                        raise cause from None
                    raise
        finally:
            for r in pending:  # interrupted, or a task failed: the others are not waited for
                self.ray.cancel(r)

    def map(self, fn, items: list) -> list:
        """``[fn(x) for x in items]``, as parallel tasks."""
        out = [None] * len(items)
        for i, r in self.as_completed(fn, items):
            out[i] = r
        return out
