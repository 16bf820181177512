"""One writer per run folder (``layercam/io/lock.py``): a second command on a folder in use refuses
with one line naming the running one; a lock left by a dead process is taken over; the lock is
released on every way out."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from layercam.cli import main
from layercam.core.errors import LayercamError
from layercam.io.lock import LOCK_NAME, lock_owner, run_lock

from conftest import tiny_argv

HOLD = """
import sys, time
from layercam.io.lock import run_lock
with run_lock(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(120)
"""


def _holder(folder: Path) -> subprocess.Popen:
    """A process that holds ``folder``'s lock until it is killed."""
    p = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "locked"
    return p


def _stopped(pid: int, timeout: float = 300) -> None:
    """Waits until process ``pid`` is stopped (SIGSTOP)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] == "T":
            return
        time.sleep(0.05)
    raise AssertionError(f"process {pid} did not stop")


def test_second_identical_command_refuses_naming_the_running_one(tiny_frames, tmp_path, capsys):
    """Issue 18 item 4: two identical commands on one --out at once. The first stops itself (SIGSTOP)
    in the middle of training, holding the lock; the second refuses in one line and touches
    nothing; the first, continued, finishes normally."""
    run = tmp_path / "run"
    argv = tiny_argv("hdr-video", tiny_frames, run, "--ev-step", "3")
    env = dict(os.environ, LAYERCAM_SIGNAL_AT="train:10:STOP")
    first = subprocess.Popen([sys.executable, "-m", "layercam", *argv], env=env, stderr=subprocess.PIPE, text=True)
    try:
        _stopped(first.pid)
        before = sorted(str(p.relative_to(run)) for p in run.rglob("*"))
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error:") and "\n" not in err, err
        assert f"in use by pid {first.pid} on {socket.gethostname()}" in err and "hdr-video" in err, err
        assert sorted(str(p.relative_to(run)) for p in run.rglob("*")) == before
    finally:
        first.send_signal(signal.SIGCONT)
    assert first.wait(timeout=300) == 0, first.stderr.read()[-2000:]
    assert (run / "report.json").is_file() and not (run / LOCK_NAME).exists()


def test_lock_of_a_dead_process_is_taken_over(tmp_path):
    holder = _holder(tmp_path)
    owner = lock_owner(tmp_path)
    assert owner["pid"] == holder.pid and owner["host"] == socket.gethostname()
    with pytest.raises(LayercamError, match=f"in use by pid {holder.pid}"):
        with run_lock(tmp_path):
            pass
    holder.kill()  # SIGKILL: no chance to clean up, the lock file stays
    holder.wait()
    assert (tmp_path / LOCK_NAME).exists()
    said = []
    with run_lock(tmp_path, said.append):
        assert lock_owner(tmp_path)["pid"] == os.getpid()
    assert said and f"stale lock of pid {holder.pid}" in said[0] and "no longer running" in said[0]
    assert not (tmp_path / LOCK_NAME).exists()


def test_lock_released_on_error_and_ctrl_c_and_reentrant(tmp_path):
    for exc in (LayercamError("boom"), KeyboardInterrupt()):
        with pytest.raises(type(exc)):
            with run_lock(tmp_path):
                with run_lock(tmp_path):  # the same process may take it again (a command calling run_task)
                    pass
                assert (tmp_path / LOCK_NAME).exists()
                raise exc
        assert not (tmp_path / LOCK_NAME).exists()
    with run_lock(tmp_path, enabled=False):  # ranks other than 0
        assert not (tmp_path / LOCK_NAME).exists()


def test_render_and_edit_refuse_a_run_in_use(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoint.pt").write_bytes(b"not read: the lock comes first")
    holder = _holder(run)
    try:
        assert main(["render", str(run), "--exposure", "1"]) == 2
        assert f"in use by pid {holder.pid}" in capsys.readouterr().err
        assert main(["edit", str(run), "--atlas", str(tmp_path / "a.png")]) == 2
        assert f"in use by pid {holder.pid}" in capsys.readouterr().err
    finally:
        holder.kill()
        holder.wait()
    assert json.loads((run / LOCK_NAME).read_text())["pid"] == holder.pid  # left by the killed holder
