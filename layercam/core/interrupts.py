"""Interruptions: Ctrl-C acted on at safe points, and a hook that interrupts a run at an exact point.

* :func:`deferred` notes a Ctrl-C (SIGINT) or SIGTERM inside its block instead of raising it where
  it lands; the code checks ``pending()`` at its safe points (the trainer: between steps, so a
  checkpoint never holds a half-applied update) and raises :class:`Interrupted` there. A second
  signal interrupts at once. Leaving the block with a signal still pending raises it.
* :func:`reached` is a test hook (fault injection): with ``LAYERCAM_SIGNAL_AT="where:i:SIG"`` in the
  environment (``SIG`` one of INT, TERM, KILL), the process sends itself ``SIG`` when ``where``
  (``train``, ``export``, ``atlas``, ``publish``, ``render``, ``edit``) reaches item ``i``. The
  interruption tests stop a run at exact points this way; without the variable it does nothing.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading

__all__ = ["Interrupted", "deferred", "reached"]

ENV = "LAYERCAM_SIGNAL_AT"


class Interrupted(KeyboardInterrupt):
    """A Ctrl-C acted on at a safe point (the state is consistent: worth saving)."""


@contextlib.contextmanager
def deferred():
    """Yields ``pending()``: whether a SIGINT/SIGTERM arrived in the block (see the module doc)."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    noted: list[int] = []

    def handler(signum, frame):
        if noted:  # the second one: at once
            raise KeyboardInterrupt
        noted.append(signum)

    sigs = (signal.SIGINT, signal.SIGTERM)
    old = {s: signal.signal(s, handler) for s in sigs}
    clean = False
    try:
        yield lambda: bool(noted)
        clean = True
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if clean and noted:
        raise Interrupted


def reached(where: str, i: int) -> None:
    """Sends this process the signal named in ``LAYERCAM_SIGNAL_AT`` when it says ``where:i``."""
    spec = os.environ.get(ENV)
    if not spec:
        return
    w, n, sig = spec.split(":")
    if w == where and int(n) == int(i):
        os.kill(os.getpid(), getattr(signal, f"SIG{sig.upper()}"))
