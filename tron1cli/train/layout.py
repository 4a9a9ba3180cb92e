"""Where a run directory keeps what (torch-free, so the CLI checks a run directory before torch loads).

- ``config.json``: the resolved run configuration (env, reward, learner, seed, ...);
- ``checkpoints/ckpt_<iteration>.pt`` and ``checkpoints/latest.pt``: versioned plain dicts of
  tensors plus the config, written atomically;
- ``metrics.jsonl``: one JSON object per iteration (throughput, per-group rewards, per-term
  episode sums, survival, episode length, tracking error, losses, learning rate, ...);
- ``train.lock``: while a run trains, the process id of the ``tron1 train`` that owns the folder
  (:class:`RunLock`), so that a second one started into it is refused.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

from tron1cli.errors import Tron1Error
from tron1cli.fileio import check_output_dir

CONFIG = "config.json"
CHECKPOINTS = "checkpoints"
LATEST = "latest.pt"
METRICS = "metrics.jsonl"
LOCK = "train.lock"


def checkpoint_dir(run_dir: Path | str) -> Path:
    """The run's checkpoint folder."""
    return Path(run_dir) / CHECKPOINTS


def latest_checkpoint(run_dir: Path | str) -> Path:
    """The run's latest checkpoint (what ``--resume`` continues from)."""
    return checkpoint_dir(run_dir) / LATEST


def check_run_dir(run_dir: Path | str, resume: bool) -> None:
    """Clear errors before anything is built: a resume without a run, a run directory that cannot
    be made or written, one another ``tron1 train`` is training in."""
    check_output_dir(run_dir, "--run-dir")
    RunLock(run_dir).check()
    if resume and not latest_checkpoint(run_dir).exists():
        raise Tron1Error(f"nothing to resume in {run_dir}: no {CHECKPOINTS}/{LATEST}")


def _start_time(pid: int) -> str | None:
    """When process ``pid`` started (clock ticks since boot, Linux's /proc); None where unknown.
    With the pid it tells a live owner from a later process that was given the same pid."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat.rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except OSError:
        return False
    return True


class RunLock:
    """The lock of a run directory: ``train.lock`` holding the owner's pid, host and start time.

    :meth:`acquire` creates it (O_EXCL) or raises :class:`Tron1Error` naming the live owner; a
    lock whose process is gone (a run killed with SIGKILL, a machine that rebooted) is stale and
    taken over. :meth:`release` removes it."""

    def __init__(self, run_dir: Path | str) -> None:
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / LOCK
        self.held = False

    def _owner(self) -> tuple[int, str, str | None] | None:
        """(pid, host, start time) of the lock's live owner; None when there is no lock or it is
        stale (unreadable, its process gone, the pid reused)."""
        try:
            fields = self.path.read_text().split()
        except FileNotFoundError:
            return None
        except OSError:
            fields = []
        try:
            pid, host = int(fields[0]), fields[1]
        except (IndexError, ValueError):
            return None  # a lock cut short when it was written: its owner never ran
        started = fields[2] if len(fields) > 2 and fields[2] != "-" else None
        if host != socket.gethostname():
            return pid, host, started  # another machine's process (a shared disk): cannot tell
        if not _alive(pid):
            return None
        now = _start_time(pid)
        if pid == os.getpid() and (started is None or now is None):
            return None  # a container restarted with the same pid: this process cannot own it yet
        if started is not None and now not in (None, started):
            return None  # the pid now belongs to another process
        return pid, host, started

    def _refusal(self, owner: tuple[int, str, str | None]) -> Tron1Error:
        pid, host, _ = owner
        where = f"process {pid}" + ("" if host == socket.gethostname() else f" on {host}")
        return Tron1Error(
            f"--run-dir {self.run_dir} is in use: another tron1 train ({where}) is training there "
            f"({self.path}); wait for it or stop it, or give another --run-dir"
        )

    def check(self) -> None:
        """Raise :class:`Tron1Error` when a live process holds the lock (without taking it)."""
        owner = self._owner()
        if owner is not None:
            raise self._refusal(owner)

    def acquire(self) -> RunLock:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        me = f"{os.getpid()} {socket.gethostname()} {_start_time(os.getpid()) or '-'}\n".encode()
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                owner = self._owner()
                if owner is not None:
                    raise self._refusal(owner) from None
                self.path.unlink(missing_ok=True)  # stale: its owner is gone
                continue
            try:
                os.write(fd, me)
            finally:
                os.close(fd)
            self.held = True
            return self
        raise Tron1Error(f"--run-dir {self.run_dir}: cannot take its lock {self.path}")

    def release(self) -> None:
        if self.held:
            self.held = False
            self.path.unlink(missing_ok=True)


def policy_label(path: Path) -> str:
    """A policy's name in tables when none is given: its run's name for a run's latest checkpoint
    (``runs/x/checkpoints/latest.pt`` -> ``x``, also given as ``checkpoints/latest.pt`` from
    inside the run), else the file's stem."""
    try:
        p = path.resolve()
    except (OSError, RuntimeError):  # a symbolic link loop: the loading step names the problem
        return path.stem
    if p.name == LATEST and p.parent.name == CHECKPOINTS and p.parent.parent.name:
        return p.parent.parent.name
    return path.stem
