"""Claiming a cell folder for one process: ``flock`` locks or lease files, behind :func:`claim`.

Two kinds of claim, chosen by ``grid.lock``:

- ``flock``: ``fcntl.flock`` (exclusive, non-blocking) on ``<folder>/.lock``. The kernel drops
  the lock when its process dies, so a lock left by a killed sweep is free at once. Needs a file
  system whose ``flock`` works across all the machines that share the folder.
- ``lease``: a lease file ``<folder>/.lease`` that only plain file operations manage, for file
  systems where ``flock`` raises (Lustre mounted without ``flock``) or holds on one machine only
  (NFS with ``local_lock``, Lustre with ``localflock``).

  - Format: two lines, ``<pid> <host>`` (the owner, as in ``.lock``) and a JSON object
    ``{"host", "pid", "pidns", "token", "ttl_s", "written", "expires"}``: ``token`` is 32 random
    hex digits naming this claim, ``ttl_s`` the lease's lifetime, ``written`` and ``expires``
    the writer's clock at the last renewal (Unix seconds; for people, never compared).
  - Creation: the content goes to a temporary file first, which is then hard-linked to
    ``.lease`` (``link`` fails when the name exists, so exactly one claimant wins, and nobody
    ever reads a half-written lease). This is also the creation NFS has always made atomic: a
    ``link`` whose reply was lost and retried reports "exists" although it worked, so "exists"
    with a link count of 2 on the temporary counts as won. On a file system without hard links
    the lease is created with ``O_CREAT | O_EXCL`` (atomic on NFS v3 and later); a contender
    that reads it half written treats it as held.
  - Heartbeat: a thread renews the lease every ``ttl_s / 3`` seconds: it reads the file, checks
    the token is still its own, writes the new content to a temporary and renames it over
    ``.lease``. A lease found taken (another token) or missing, or not renewed for ``ttl_s``
    because of errors, is lost: the heartbeat stops and logs it (the cell may then be computed
    twice; its record is written atomically either way).
  - Expiry: a lease is stale when its file's modification time is more than the ``ttl_s`` it
    records older than the modification time of a probe file the contender writes into the same
    folder just then. Both times are stamped by the file system (the NFS server's clock; on
    Lustre the writing clients' clocks, which a cluster keeps within a second by NTP), so the
    contender's own clock never enters and skew between the machines cancels. A lease written by
    a process on this machine (same host name and PID namespace) whose process no longer exists
    is stale at once.
  - Breaking: a contender renames a stale ``.lease`` to a unique name, reads what it moved and
    compares it (inode, modification time, content) with what it judged stale; the same: it
    deletes it and creates its own; not the same (renewed or replaced meanwhile): it links it
    back and leaves the cell to its owner.
  - Release: the lease is removed the same way, only while it still holds this claim's token.

- ``auto`` (the default): per file system (device of the folder), once per process: ``lease``
  when ``flock`` on a probe file raises (``ENOLCK``, ``EOPNOTSUPP``, ``ENOSYS``, ``EINVAL``, ...)
  or when ``/proc/mounts`` says the folder's mount has a ``flock`` that other machines do not
  see (:func:`mount_rule`: NFS with ``nolock`` or ``local_lock=all|flock``, Lustre without
  ``flock``, BeeGFS); else ``flock``.

Every process working in one folder must claim the same kind (``auto`` picks the same one on
every machine that mounts the file system alike). Temporaries are named ``.<hex>.lease-*.tmp``:
a killed process's are removed as leftovers by the next process that computes the cell.
"""

from __future__ import annotations

import errno
import fcntl
import json
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
from pathlib import Path

from snell_bench.utils.io import umask_mode

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
LEASE_NAME = ".lease"  #: the ``lease`` kind's file
CLAIM_NAMES = (LOCK_NAME, LEASE_NAME)
DEFAULT_TTL_S = 120.0

HOST = socket.gethostname()


def _pid_namespace() -> str:
    try:
        return os.readlink("/proc/self/ns/pid")
    except OSError:
        return ""


PIDNS = _pid_namespace()


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
    a lease's lifetime without renewal. The claim file is removed when the block ends."""
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
    """Hold ``folder/.lock`` (``fcntl.flock``, exclusive, non-blocking) for the block. The kernel
    drops the lock when its process dies, so a lock left by a killed sweep is free again."""
    path = folder / LOCK_NAME
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, umask_mode())
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            yield False
            return
        except BaseException:
            os.close(fd)
            raise
        try:  # the file may have been removed (and another made) while we waited: lock the one at path
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {HOST}\n".encode())
        yield True
    finally:
        try:
            os.unlink(path)
        finally:
            os.close(fd)


# ---------------------------------------------------------------------------- leases
@dataclass(frozen=True)
class _Seen:
    """A lease file as read: its bytes, inode and modification time."""

    data: bytes
    ino: int
    mtime_ns: int

    def record(self) -> dict | None:
        try:
            rec = json.loads(self.data.decode().strip().splitlines()[-1])
        except (ValueError, IndexError):
            return None
        return rec if isinstance(rec, dict) else None


def _read(path: Path) -> _Seen | None:
    """The file at ``path`` (opened, so NFS revalidates its attributes), or ``None`` when missing."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        st = os.fstat(fd)
        data = os.read(fd, 1 << 16)
    finally:
        os.close(fd)
    return _Seen(data, st.st_ino, st.st_mtime_ns)


def _temporary(folder: Path, what: str) -> Path:
    return folder / f".{secrets.token_hex(8)}.lease-{what}.tmp"


def _write_new(path: Path, data: bytes) -> None:
    """Write ``data`` to a file ``path`` that must not exist yet."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, umask_mode())
    try:
        os.write(fd, data)
    finally:
        os.close(fd)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True
    return True


class Lease:
    """One claim of a lease file (see the module docs): :meth:`acquire`, then :meth:`release`.

    Args:
        path: the lease file (``<folder>/.lease``).
        ttl_s: seconds a lease lives without renewal; it is renewed every ``ttl_s / 3``.
    """

    def __init__(self, path: str | os.PathLike, ttl_s: float = DEFAULT_TTL_S) -> None:
        self.path = Path(path)
        self.folder = self.path.parent
        self.ttl_s = float(ttl_s)
        self.token = secrets.token_hex(16)
        self.lost: str | None = None  #: why the lease stopped being ours while held, or None
        self._stop = threading.Event()
        self._heartbeat: threading.Thread | None = None

    def content(self) -> bytes:
        """The lease file's text for this claim now."""
        now = time.time()
        rec = {
            "host": HOST,
            "pid": os.getpid(),
            "pidns": PIDNS,
            "token": self.token,
            "ttl_s": self.ttl_s,
            "written": round(now, 3),
            "expires": round(now + self.ttl_s, 3),
        }
        return f"{os.getpid()} {HOST}\n{json.dumps(rec)}\n".encode()

    # ------------------------------------------------------------------------ taking it
    def acquire(self) -> bool:
        """Create the lease, breaking a stale one first; ``False`` when another process holds it."""
        for _ in range(4):
            if self._create():
                self._heartbeat = threading.Thread(target=self._renew_loop, name="lease-heartbeat", daemon=True)
                self._heartbeat.start()
                return True
            seen = _read(self.path)
            if seen is None:
                continue  # released meanwhile
            why = self.stale(seen)
            if why is None:
                return False
            if self._take_aside(seen):
                log.info("broke the lease %s: %s", self.path, why)
        return False

    def _create(self) -> bool:
        tmp = _temporary(self.folder, "new")
        try:
            _write_new(tmp, self.content())
        except FileNotFoundError:
            return False  # removed as a leftover by the cell's holder: the cell is held
        try:
            os.link(tmp, self.path)
            return True
        except FileExistsError:
            try:  # NFS: a retried link that had worked reports "exists"
                return os.stat(tmp).st_nlink == 2
            except FileNotFoundError:
                return False
        except FileNotFoundError:
            return False
        except OSError as e:
            if e.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS, errno.EMLINK, errno.EXDEV):
                raise
        finally:
            tmp.unlink(missing_ok=True)
        try:  # no hard links here: an exclusive create
            _write_new(self.path, self.content())
        except FileExistsError:
            return False
        return True

    def stale(self, seen: _Seen) -> str | None:
        """Why the lease ``seen`` may be broken (see the module docs), or ``None``: it is held."""
        rec = seen.record() or {}
        if rec.get("host") == HOST and rec.get("pidns", "") == PIDNS and isinstance(rec.get("pid"), int):
            if not _alive(rec["pid"]):
                return f"its process {rec['pid']} on this machine is gone"
        try:
            ttl = check_ttl(rec.get("ttl_s", self.ttl_s))
        except ValueError:
            ttl = self.ttl_s
        now = self._file_system_now_ns()
        if now is None:
            return None
        age = (now - seen.mtime_ns) / 1e9
        if age > ttl:
            return f"not renewed for {age:.1f} s (ttl {ttl:g} s)"
        return None

    def _file_system_now_ns(self) -> int | None:
        """The file system's clock now: the modification time of a probe file written in the folder."""
        probe = _temporary(self.folder, "probe")
        try:
            _write_new(probe, b"\n")
            return os.stat(probe).st_mtime_ns
        except OSError:
            return None
        finally:
            probe.unlink(missing_ok=True)

    def _take_aside(self, seen: _Seen) -> bool:
        """Move the lease ``seen`` away and delete it, atomically: ``True`` when exactly that
        file was removed; ``False`` when the file there had changed (it is put back)."""
        aside = _temporary(self.folder, "broken")
        try:
            os.rename(self.path, aside)
        except FileNotFoundError:
            return False
        try:
            moved = _read(aside)
            if moved == seen:
                return True
            try:  # another lease than the one judged: put it back (never over a newer one)
                os.link(aside, self.path)
            except FileExistsError:
                log.warning("a lease of %s was replaced while being broken; its owner loses it", self.path)
            except OSError:
                if not self.path.exists():
                    os.rename(aside, self.path)
            return False
        finally:
            aside.unlink(missing_ok=True)

    # ------------------------------------------------------------------------ holding it
    def _renew_loop(self) -> None:
        interval = self.ttl_s / 3
        last_ok = time.monotonic()
        while not self._stop.wait(interval):
            try:
                seen = _read(self.path)
                if seen is None or (seen.record() or {}).get("token") != self.token:
                    owner = "" if seen is None else f" (now {seen.data.decode(errors='replace').splitlines()[0]})"
                    self.lost = "the lease was removed" if seen is None else f"the lease was taken{owner}"
                    break
                tmp = _temporary(self.folder, "renew")
                try:
                    _write_new(tmp, self.content())
                    os.replace(tmp, self.path)
                finally:
                    tmp.unlink(missing_ok=True)
                last_ok = time.monotonic()
            except OSError as e:
                if time.monotonic() - last_ok > self.ttl_s:
                    self.lost = f"not renewed for {self.ttl_s:g} s ({type(e).__name__}: {e})"
                    break
                log.debug("renewing %s failed (%s); trying again", self.path, e)
        if self.lost is not None:
            log.warning("lost the claim of %s: %s; another process may compute it too", self.folder, self.lost)

    def release(self) -> None:
        """Stop renewing and remove the lease if it is still this claim's."""
        self._stop.set()
        if self._heartbeat is not None:
            self._heartbeat.join()
            self._heartbeat = None
        seen = _read(self.path)
        if seen is not None and (seen.record() or {}).get("token") == self.token:
            self._take_aside(seen)
