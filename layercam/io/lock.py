"""One writer per run folder: ``RUN/layercam.lock``.

The lock is an exclusive ``flock`` on the file, held for as long as the command runs; the file says
who holds it (pid, host, the command line, since when) so that a second command on the same folder
can refuse with one line naming the running one. The kernel drops a ``flock`` when its process ends,
however it ends (Ctrl-C, an error, SIGKILL), so a lock file left behind by a dead process is stale
and simply taken over by the next command (and said so). Under torch.distributed only rank 0 takes
the lock (the other ranks write nothing of their own).

Re-entrant within a process: a command that holds the lock may call code that takes it again.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import socket
import sys
import time
from pathlib import Path

from layercam.core.errors import LayercamError

__all__ = ["LOCK_NAME", "run_lock", "lock_owner"]

LOCK_NAME = "layercam.lock"
_held: dict[str, list] = {}  # resolved lock path -> [fd, depth]


def _owner_record() -> dict:
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "command": " ".join(["layercam", *sys.argv[1:]]) if sys.argv and "layercam" in sys.argv[0]
        else " ".join(sys.argv),
        "since": time.strftime("%Y-%m-%d %H:%M:%S"),
    }


def lock_owner(folder: str | os.PathLike) -> dict | None:
    """What ``folder``'s lock file says about its holder (None when there is none or it is unreadable)."""
    try:
        return json.loads((Path(folder) / LOCK_NAME).read_text())
    except (OSError, ValueError):
        return None


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this machine (one we may not signal counts as running)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _describe(owner: dict | None) -> str:
    if not owner:
        return "another layercam command"
    return f"pid {owner.get('pid')} on {owner.get('host')} since {owner.get('since')} ({owner.get('command')})"


def _acquire(path: Path, say) -> int:
    import fcntl

    for _ in range(20):  # retried when the file is replaced between open and lock
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            if e.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):  # a file system without locks
                say(f"cannot lock {path} ({e.strerror}): going on without a lock")
                return fd
            os.close(fd)
            owner = lock_owner(path.parent)
            raise LayercamError(f"{path.parent} is in use by {_describe(owner)}; wait for it to "
                                "finish or choose another --out") from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if not same:  # the holder released (and removed) it meanwhile: lock the file that is there now
            os.close(fd)
            continue
        old = os.read(fd, 4096)
        if old.strip():
            try:
                prev = json.loads(old)
            except ValueError:
                prev = None
            here = prev and prev.get("host") == socket.gethostname()
            state = "no longer running" if here and not pid_alive(int(prev.get("pid",
                -1))) else "ended without removing it"
            say(f"taking over a stale lock of {_describe(prev)}: {state}")
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, (json.dumps(_owner_record()) + "\n").encode())
        os.fsync(fd)
        return fd
    raise LayercamError(f"cannot take the lock {path}: it keeps being replaced")


@contextlib.contextmanager
def run_lock(folder: str | os.PathLike, say=None, enabled: bool = True):
    """Hold ``folder/layercam.lock`` for the duration of the ``with`` block (creating ``folder``).

    Raises ``LayercamError`` (one line naming the holder) when another process holds it. The lock
    file is removed on the way out, whatever the way out. ``enabled=False`` (ranks other than 0)
    does nothing.
    """
    if not enabled:
        yield
        return
    from layercam.io.atomic import ensure_writable_dir

    folder = ensure_writable_dir(folder)
    path = folder.resolve() / LOCK_NAME
    key = str(path)
    if key in _held:
        _held[key][1] += 1
        try:
            yield
        finally:
            _held[key][1] -= 1
        return
    fd = _acquire(path, say or (lambda m: print(m, file=sys.stderr, flush=True)))
    _held[key] = [fd, 1]
    try:
        yield
    finally:
        del _held[key]
        with contextlib.suppress(OSError):
            path.unlink()  # while still locked: a waiting opener then finds a new inode and retries
        os.close(fd)
