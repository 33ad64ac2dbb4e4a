"""Claiming a cell folder for one process: ``flock`` (filelock) or an NFS-safe lease (flufl.lock).

Two kinds of claim, chosen by ``grid.lock``:

- ``flock``: :class:`filelock.UnixFileLock` (``fcntl.flock``, exclusive, non-blocking) on
  ``<folder>/.lock``. The kernel drops the lock when its process dies, so a lock left by a killed
  sweep is free at once. The file stays in place (so that every claimant locks the same inode);
  while held it holds its owner's ``<pid> <host>`` line, which ``job=status`` shows, and it is
  emptied on release. Needs a file system whose ``flock`` works across all the machines that
  share the folder.
- ``lease``: :class:`flufl.lock.Lock` on ``<folder>/.lease``, for file systems where ``flock``
  raises (Lustre mounted without ``flock``) or holds on one machine only (NFS with
  ``local_lock``, Lustre with ``localflock``). The claim is a hard link from a claim file
  ``.lease|<host>|<pid>|<n>`` (which the lease file's text names) to ``.lease``: ``link`` is the
  creation NFS makes atomic. Its lifetime is ``grid.lease_ttl_s``, stamped as the lease file's
  modification time and renewed every ``ttl / 3`` seconds by a heartbeat thread; a lease found
  taken or removed while held is lost (logged: the cell may then be computed twice; its record
  is written atomically either way). A contender breaks a lease expired by more than flufl's
  clock slop (10 s, the skew allowed between the machines' clocks), or at once when its owner is
  a process of this machine that no longer exists.
- ``auto`` (the default): per file system (device of the folder), once per process: ``lease``
  when ``flock`` on a probe file raises (``ENOLCK``, ``EOPNOTSUPP``, ``ENOSYS``, ``EINVAL``, ...)
  or when ``/proc/mounts`` says the folder's mount has a ``flock`` that other machines do not
  see (:func:`mount_rule`: NFS with ``nolock`` or ``local_lock=all|flock``, Lustre without
  ``flock``, BeeGFS); else ``flock``.

Every process working in one folder must claim the same kind (``auto`` picks the same one on
every machine that mounts the file system alike).
"""

from __future__ import annotations

import errno
import fcntl
import logging
import math
import os
import re
import secrets
import socket
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import filelock
from flufl.lock import Lock, LockState, NotLockedError, TimeOutError

log = logging.getLogger(__name__)

__all__ = [
    "KINDS",
    "LOCK_NAME",
    "LEASE_NAME",
    "CLAIM_NAMES",
    "DEFAULT_TTL_S",
    "LockUnsupported",
    "Lease",
    "claim",
    "hold",
    "choose_lock",
    "check_ttl",
    "probe_flock",
    "mount_of",
    "mount_rule",
]

KINDS = ("auto", "flock", "lease")
LOCK_NAME = ".lock"  #: the ``flock`` kind's file
LEASE_NAME = ".lease"  #: the ``lease`` kind's file (its claim files are ``.lease|...``)
CLAIM_NAMES = (LOCK_NAME, LEASE_NAME)
DEFAULT_TTL_S = 120.0

HOST = socket.gethostname()
CLOCK_SLOP = timedelta(seconds=10)  #: flufl.lock's: a lease is broken this long after it expired


class LockUnsupported(RuntimeError):
    """``flock`` was asked for on a file system where it raises."""


# ---------------------------------------------------------------------------- choosing the kind
def check_ttl(ttl_s: float, key: str = "grid.lease_ttl_s") -> float:
    """``ttl_s`` as a float, or a :class:`ValueError` naming ``key`` when it is not a finite number > 0."""
    try:
        ok = not isinstance(ttl_s, bool) and math.isfinite(float(ttl_s)) and float(ttl_s) > 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{key}={ttl_s!r}: must be a finite number of seconds > 0; e.g. {key}={DEFAULT_TTL_S:g}")
    return float(ttl_s)


def mount_of(path: str | os.PathLike, mounts: str | None = None) -> tuple[str, str, dict] | None:
    """``(mount point, file system type, options)`` of the mount holding ``path``, read from
    ``mounts`` (the text of ``/proc/mounts``; read here when ``None``), or ``None`` when unknown.
    Options are ``{name: value}``, ``True`` for a flag. The last of stacked mounts wins."""
    if mounts is None:
        try:
            mounts = Path("/proc/mounts").read_text()
        except OSError:
            return None
    real = os.path.realpath(path)
    best = None
    for line in mounts.splitlines():
        parts = line.split()
        if len(parts) < 4:
            continue
        point = re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), parts[1])  # \040: a space
        if (real == point or real.startswith(point.rstrip("/") + "/")) and (best is None or len(point) >= len(best[0])):
            options = dict(o.split("=", 1) if "=" in o else (o, True) for o in parts[3].split(","))
            best = (point, parts[2], options)
    return best


def mount_rule(fstype: str, options: dict) -> str | None:
    """Why ``flock`` on a mount of type ``fstype`` with ``options`` would not exclude processes on
    other machines (so ``auto`` takes leases), or ``None``:

    - ``nfs``/``nfs4`` with ``nolock``, ``local_lock=all`` or ``local_lock=flock``: the client
      keeps flock locks to itself (without them Linux sends flock to the server as a lock on the
      whole file, which other clients see);
    - ``lustre`` without ``flock``: ``localflock`` locks on one client only, and without either
      option flock raises;
    - ``beegfs``: its client checks flock locally unless ``tuneUseGlobalFileLocks`` is set in
      ``beegfs-client.conf``, which the mount options do not show.

    Examples:
        >>> mount_rule("nfs4", {"rw": True, "local_lock": "none"}) is None
        True
        >>> mount_rule("lustre", {"localflock": True})
        'lustre mounted without flock'
    """
    if fstype in ("nfs", "nfs4"):
        if options.get("nolock") or options.get("local_lock") in ("all", "flock"):
            return f"{fstype} with local flock locks (nolock or local_lock=all|flock)"
    elif fstype == "lustre":
        if not options.get("flock"):
            return "lustre mounted without flock"
    elif fstype == "beegfs":
        return "beegfs (flock is local to each client by default)"
    return None


def probe_flock(folder: str | os.PathLike) -> OSError | None:
    """The error ``fcntl.flock`` raises on a new file in ``folder``, or ``None`` when it works."""
    fd, probe = tempfile.mkstemp(dir=folder, prefix=f".{secrets.token_hex(8)}.", suffix=".lock-probe.tmp")
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
    except BlockingIOError:
        return None  # locks exist here (nobody else can hold a new file's lock, but that is no failure)
    except OSError as e:
        return e
    finally:
        os.close(fd)
        Path(probe).unlink(missing_ok=True)
    return None


@dataclass(frozen=True)
class _FileSystem:
    mount_reason: str | None  #: why the mount's flock is local only, or None
    flock_error: OSError | None  #: what flock raised on a probe file, or None


_FILE_SYSTEMS: dict[int, _FileSystem] = {}  #: device -> what was found (once per process)


def _file_system(folder: Path) -> _FileSystem:
    dev = os.stat(folder).st_dev
    if dev not in _FILE_SYSTEMS:
        mount = mount_of(folder)
        _FILE_SYSTEMS[dev] = _FileSystem(mount and mount_rule(mount[1], mount[2]), probe_flock(folder))
    return _FILE_SYSTEMS[dev]


def choose_lock(kind: str, folder: str | os.PathLike, *, key: str = "grid.lock") -> str:
    """The kind (``flock`` or ``lease``) that claims cells under ``folder`` for ``kind`` (see the
    module docs); ``auto`` decides once per file system in this process.

    Raises:
        ValueError: ``kind`` is none of :data:`KINDS` (the message names ``key``).
        LockUnsupported: ``kind`` is ``flock`` and flock raises on this file system.
    """
    if kind not in KINDS:
        raise ValueError(f"{key}={kind!r}: must be one of {', '.join(KINDS)}; e.g. {key}=auto")
    if kind == "lease":
        return "lease"
    folder = Path(folder)
    fresh = os.stat(folder).st_dev not in _FILE_SYSTEMS
    fs = _file_system(folder)
    if kind == "flock":
        if fs.flock_error is not None:
            raise LockUnsupported(
                f"{key}=flock: flock does not work in {folder} ({type(fs.flock_error).__name__}: "
                f"{fs.flock_error}); set {key}=lease (or {key}=auto)"
            )
        return "flock"
    if fs.flock_error is not None:
        chosen, why = "lease", f"flock raises {errno.errorcode.get(fs.flock_error.errno, fs.flock_error.errno)}"
    elif fs.mount_reason is not None:
        chosen, why = "lease", fs.mount_reason
    else:
        chosen, why = "flock", "flock works here"
    if fresh:
        log.info("cells under %s are claimed with %s (%s=auto: %s)", folder, chosen, key, why)
    return chosen


# ---------------------------------------------------------------------------- the claim
@contextmanager
def claim(folder: str | os.PathLike, kind: str = "auto", ttl_s: float = DEFAULT_TTL_S) -> Iterator[bool]:
    """Claim ``folder`` for the block: ``True`` when this process has it, ``False`` when another
    one holds it. ``kind``: ``flock``, ``lease`` or ``auto`` (:func:`choose_lock`); ``ttl_s``:
    a lease's lifetime without renewal."""
    folder = Path(folder)
    kind = choose_lock(kind, folder)
    if kind == "flock":
        with _flock(folder) as mine:
            yield mine
        return
    lease = Lease(folder / LEASE_NAME, check_ttl(ttl_s))
    if not lease.acquire():
        yield False
        return
    try:
        yield True
    finally:
        lease.release()


@contextmanager
def hold(
    folder: str | os.PathLike, kind: str = "auto", ttl_s: float = DEFAULT_TTL_S, *, poll_s: float = 0.2
) -> Iterator[None]:
    """Wait until this process has the claim of ``folder`` (:func:`claim`, polled every ``poll_s``
    seconds), then hold it for the block: for work that must not run twice at once in one folder,
    such as two shards of a grid writing the same report."""
    folder = Path(folder)
    kind = choose_lock(kind, folder)
    while True:
        with claim(folder, kind, ttl_s) as mine:
            if mine:
                yield
                return
        time.sleep(poll_s)


@contextmanager
def _flock(folder: Path) -> Iterator[bool]:
    """Hold ``folder/.lock`` for the block (filelock's flock, non-blocking), with the owner's line in it."""
    lock = filelock.UnixFileLock(str(folder / LOCK_NAME), timeout=0, thread_local=False)
    try:
        lock.acquire()
    except filelock.Timeout:
        yield False
        return
    owner = folder / LOCK_NAME
    try:
        owner.write_text(f"{os.getpid()} {HOST}\n")
        yield True
    finally:
        try:
            owner.write_text("")
        finally:
            lock.release()


# ---------------------------------------------------------------------------- leases
class Lease:
    """One claim of a lease file (see the module docs): :meth:`acquire`, then :meth:`release`.

    Args:
        path: the lease file (``<folder>/.lease``).
        ttl_s: seconds a lease lives without renewal; it is renewed every ``ttl_s / 3``.
    """

    def __init__(self, path: str | os.PathLike, ttl_s: float = DEFAULT_TTL_S) -> None:
        self.path = Path(path)
        self.ttl_s = float(ttl_s)
        self.lock = Lock(str(self.path), lifetime=timedelta(seconds=self.ttl_s))
        self.lost: str | None = None  #: why the lease stopped being ours while held, or None
        self._stop = threading.Event()
        self._heartbeat: threading.Thread | None = None

    def acquire(self) -> bool:
        """Take the lease, breaking a stale one first; ``False`` when another process holds it."""
        for _ in range(3):
            try:
                self.lock.lock(timeout=timedelta(0))
                break
            except TimeOutError:
                pass
            why = self._stale()
            if why is None:
                if self.path.exists():
                    return False
                continue  # released meanwhile
            if why == "gone":  # make it expired, so that flufl's lock() breaks it
                os.utime(self.path, (0, 0))
            try:  # lock() breaks an expired lease once its timeout allows a second round
                self.lock.lock(timeout=timedelta(seconds=0.05))
            except TimeOutError:
                return False
            log.info("broke the lease %s (%s)", self.path, why)
            break
        else:
            return False
        self._heartbeat = threading.Thread(target=self._renew_loop, name="lease-heartbeat", daemon=True)
        self._heartbeat.start()
        return True

    def _stale(self) -> str | None:
        """Why the lease there may be broken (``gone``: its owner was a process of this machine that
        no longer exists; ``expired``), or ``None``. Only a lease whose claim file is of this folder
        and name is ever broken (breaking deletes the claim file it names)."""
        try:
            _host, _pid, name = self.lock.details
            if name != self.lock.lockfile:
                return None
            if self.lock.state is LockState.stale:
                return "gone"
            return "expired" if self.lock.expiration + CLOCK_SLOP < datetime.now() else None
        except (NotLockedError, OSError):
            return None  # released meanwhile, or not a lease flufl wrote

    def _renew_loop(self) -> None:
        interval = self.ttl_s / 3
        last_ok = time.monotonic()
        while not self._stop.wait(interval):
            try:
                self.lock.refresh(timedelta(seconds=self.ttl_s))
                last_ok = time.monotonic()
            except NotLockedError:
                self.lost = "the lease was taken or removed"
                break
            except OSError as e:
                if time.monotonic() - last_ok > self.ttl_s:
                    self.lost = f"not renewed for {self.ttl_s:g} s ({type(e).__name__}: {e})"
                    break
                log.debug("renewing %s failed (%s); trying again", self.path, e)
        if self.lost is not None:
            log.warning("lost the claim of %s: %s; another process may compute it too", self.path.parent, self.lost)

    def release(self) -> None:
        """Stop renewing and remove the lease if it is still this claim's."""
        self._stop.set()
        if self._heartbeat is not None:
            self._heartbeat.join()
            self._heartbeat = None
        self.lock.unlock(unconditionally=True)
