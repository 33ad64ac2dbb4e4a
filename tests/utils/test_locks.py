"""Claiming a cell: flock locks and lease files exclude other claimants (threads and processes),
leases are renewed while held, broken once their owner is gone or they expired past the clock
slop, and only when they name a claim file of their own folder; removed only by their owner;
``auto`` takes leases where flock raises or is local to one machine."""

import errno
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
from omegaconf import OmegaConf

from snell_bench.experiment.cells import Cell, Policy, run_cells
from snell_bench.utils import locks
from snell_bench.utils.locks import LEASE_NAME, LOCK_NAME, Lease, LockUnsupported, choose_lock, claim

# claims each "folder kind" pair given on the command line; prints held/busy for each; with
# "hold", keeps its claims until stdin closes
CHILD = """
import contextlib, sys
from snell_bench.utils.locks import claim
with contextlib.ExitStack() as stack:
    for arg in sys.argv[2:]:
        folder, kind = arg.rsplit("=", 1)
        print("held" if stack.enter_context(claim(folder, kind=kind, ttl_s=30)) else "busy", flush=True)
    if sys.argv[1] == "hold":
        sys.stdin.read()
"""


def child(mode, *claims):
    return subprocess.Popen(
        [sys.executable, "-c", CHILD, mode, *[f"{folder}={kind}" for folder, kind in claims]],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )


def in_thread(folder, kind, ttl_s=30.0):
    out = []
    t = threading.Thread(target=lambda: out.append(_try(folder, kind, ttl_s)))
    t.start()
    t.join(10)
    return out[0]


def _try(folder, kind, ttl_s):
    with claim(folder, kind=kind, ttl_s=ttl_s) as mine:
        return mine


def dotfiles(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def lease_file(folder, *, host, pid, expires_in_s):
    """A lease as flufl.lock writes it for another process (``pid`` on ``host``): a claim file linked
    to ``.lease``, naming itself, whose modification time is the lease's expiry."""
    path = folder / LEASE_NAME
    for p in folder.iterdir():
        if p.name.startswith(LEASE_NAME):
            p.unlink()
    claimfile = folder / f"{LEASE_NAME}|{host}|{pid}|12345"
    claimfile.write_text(f"{path}|{host}|{pid}|12345")
    os.link(claimfile, path)
    t = time.time() + expires_in_s
    os.utime(path, (t, t))
    return path


def owner(folder, kind):
    """The owner line a claim file shows (``job=status`` reads the same)."""
    if kind == "flock":
        return (folder / LOCK_NAME).read_text().strip()
    _path, host, pid, _n = (folder / LEASE_NAME).read_text().split("|")
    return f"{pid} {host}"


def test_a_held_claim_refuses_a_thread_and_another_process_and_is_free_after(tmp_path):
    folders = {kind: tmp_path / kind for kind in ("flock", "lease")}
    for f in folders.values():
        f.mkdir()
    with claim(folders["flock"], kind="flock") as a, claim(folders["lease"], kind="lease") as b:
        assert a and b
        assert dotfiles(folders["flock"]) == [LOCK_NAME] and dotfiles(folders["lease"])[0] == LEASE_NAME
        assert dotfiles(folders["lease"])[1].startswith(f"{LEASE_NAME}|")  # the claim file, linked
        assert owner(folders["flock"], "flock").split()[0] == str(os.getpid())
        assert owner(folders["lease"], "lease").split()[0] == str(os.getpid())
        assert not in_thread(folders["flock"], "flock") and not in_thread(folders["lease"], "lease")
        proc = child("try", *[(f, kind) for kind, f in folders.items()])
        out, _ = proc.communicate(timeout=60)
        assert out.split() == ["busy", "busy"]
    assert dotfiles(folders["flock"]) == [LOCK_NAME] and owner(folders["flock"], "flock") == ""  # emptied
    assert dotfiles(folders["lease"]) == []  # removed
    for kind, f in folders.items():
        assert in_thread(f, kind)


def test_a_lease_of_a_killed_process_on_this_machine_is_taken_at_once(tmp_path):
    proc = child("hold", (tmp_path, "lease"))
    try:
        assert proc.stdout.readline().strip() == "held"
        assert not in_thread(tmp_path, "lease")  # its owner lives
        assert owner(tmp_path, "lease").split()[0] == str(proc.pid)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    assert len(dotfiles(tmp_path)) == 2  # a killed process leaves its lease and claim file
    with claim(tmp_path, kind="lease", ttl_s=30) as mine:  # far from expired, but its process is gone
        assert mine and owner(tmp_path, "lease").split()[0] == str(os.getpid())
    assert dotfiles(tmp_path) == []


def test_a_lease_is_broken_once_expired_by_more_than_the_clock_slop(tmp_path):
    # another machine (its pid cannot be checked here)
    lease_file(tmp_path, host="node-elsewhere", pid=4242, expires_in_s=60)
    assert not in_thread(tmp_path, "lease")
    lease_file(tmp_path, host="node-elsewhere", pid=4242, expires_in_s=-5)  # expired, within the slop
    assert not in_thread(tmp_path, "lease") and owner(tmp_path, "lease") == "4242 node-elsewhere"
    lease_file(tmp_path, host="node-elsewhere", pid=4242, expires_in_s=-60)
    with claim(tmp_path, kind="lease") as mine:
        assert mine and owner(tmp_path, "lease").split()[0] == str(os.getpid())
    assert dotfiles(tmp_path) == []  # the old claim file went with the lease it named


def test_a_lease_naming_a_file_elsewhere_is_never_broken(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (tmp_path / "cell").mkdir()
    path = tmp_path / "cell" / LEASE_NAME
    path.write_text(f"{victim}|node-elsewhere|4242|1")  # breaking deletes the claim file a lease names
    os.utime(path, (0, 0))
    assert not in_thread(tmp_path / "cell", "lease")
    assert victim.read_text() == "keep me"


def test_a_held_lease_is_renewed_past_its_ttl(tmp_path):
    lease = Lease(tmp_path / LEASE_NAME, ttl_s=1.0)
    assert lease.acquire()
    try:
        first = os.stat(tmp_path / LEASE_NAME).st_mtime
        time.sleep(2.5)  # past its lifetime
        assert os.stat(tmp_path / LEASE_NAME).st_mtime > first  # renewed: its expiry moved on
        assert not in_thread(tmp_path, "lease", ttl_s=1.0)
        assert lease.lost is None
    finally:
        lease.release()
    assert dotfiles(tmp_path) == []


def test_release_removes_only_its_own_lease_and_a_taken_lease_is_reported_lost(tmp_path):
    lease = Lease(tmp_path / LEASE_NAME, ttl_s=0.3)
    assert lease.acquire()
    theirs = lease_file(tmp_path, host="node-elsewhere", pid=4242, expires_in_s=30)  # another claimant took it
    time.sleep(0.45)  # the heartbeat finds it
    assert lease.lost and "taken" in lease.lost
    lease.release()
    assert owner(tmp_path, "lease") == "4242 node-elsewhere" and theirs.exists()


@pytest.fixture
def fresh_choice(monkeypatch):
    """Forget what auto decided, and see a plain local mount, whatever this machine's is."""
    monkeypatch.setattr(locks, "_FILE_SYSTEMS", {})
    monkeypatch.setattr(locks, "mount_of", lambda path, mounts=None: ("/", "ext4", {"rw": True}))


def test_auto_takes_flock_where_it_works_and_leases_where_it_raises(tmp_path, monkeypatch, fresh_choice):
    assert choose_lock("auto", tmp_path) == "flock" and choose_lock("flock", tmp_path) == "flock"
    monkeypatch.setattr(locks, "_FILE_SYSTEMS", {})

    def no_flock(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(locks.fcntl, "flock", no_flock)
    assert choose_lock("auto", tmp_path) == "lease"
    with pytest.raises(LockUnsupported, match=r"grid.lock=flock: flock does not work .*set grid.lock=lease"):
        choose_lock("flock", tmp_path)
    with claim(tmp_path) as mine:
        assert mine and dotfiles(tmp_path)[0] == LEASE_NAME
    calls = []
    with pytest.raises(LockUnsupported):  # forced flock stops the run before any cell
        run_cells(
            cells_in(tmp_path, ["a"]), lambda c, s: calls.append(c) or {}, root=tmp_path, policy=Policy(lock="flock")
        )
    assert calls == []
    summary = run_cells(cells_in(tmp_path, ["a", "b"]), lambda c, s: {}, root=tmp_path)
    assert summary["ok"] == 2 and summary["failed"] == 0


def test_auto_takes_leases_where_the_mount_keeps_flock_local(tmp_path, monkeypatch, fresh_choice):
    monkeypatch.setattr(locks, "mount_of", lambda p, m=None: ("/scratch", "lustre", {"localflock": True}))
    assert choose_lock("auto", tmp_path) == "lease"
    assert choose_lock("flock", tmp_path) == "flock"  # asked for: obeyed


MOUNTS = r"""/dev/vda / ext4 rw,relatime 0 0
srv:/export /home nfs4 rw,vers=4.2,local_lock=none,addr=10.0.0.1 0 0
srv:/scratch /home/my\040runs nfs rw,vers=3,nolock,local_lock=all 0 0
lfs@tcp:/lfs /lustre lustre rw,flock,lazystatfs 0 0
"""


def test_the_mount_of_a_folder_and_the_rule_that_reads_it(tmp_path):
    assert locks.mount_of("/home/me/runs", MOUNTS) == (
        "/home",
        "nfs4",
        {"rw": True, "vers": "4.2", "local_lock": "none", "addr": "10.0.0.1"},
    )
    point, fstype, options = locks.mount_of("/home/my runs/exp", MOUNTS)
    assert (point, fstype, options["local_lock"]) == ("/home/my runs", "nfs", "all")
    assert locks.mount_of("/lustre/x", MOUNTS)[1] == "lustre" and locks.mount_of("/tmp", MOUNTS)[0] == "/"
    rule = locks.mount_rule
    assert rule("nfs4", {"local_lock": "none"}) is None and rule("nfs", {}) is None
    assert (
        rule("nfs", {"nolock": True}) and rule("nfs4", {"local_lock": "flock"}) and rule("nfs4", {"local_lock": "all"})
    )
    assert rule("lustre", {"flock": True}) is None and rule("lustre", {"localflock": True}) and rule("lustre", {})
    assert rule("beegfs", {}) and rule("ext4", {}) is None and rule("xfs", {}) is None


def cells_in(root, names):
    cfg = OmegaConf.create({"x": 1, "output_dir": ""})
    return [Cell(name=n, folder=root / n, config=cfg, record={"name": n}) for n in names]


@pytest.mark.parametrize("kind", ["flock", "lease", "auto"])
def test_run_cells_claims_with_each_kind_and_leaves_no_claim(tmp_path, kind):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / ".image.png.k3j2.tmp").write_bytes(b"partial")  # a killed run's temporary
    held = {}

    def fn(cell, shared):
        held[cell.name] = dotfiles(cell.folder)
        return {}

    summary = run_cells(cells_in(tmp_path, ["a", "b"]), fn, root=tmp_path, policy=Policy(lock=kind, lease_ttl_s=5))
    assert summary["ok"] == 2 and summary["failed"] == 0
    chosen = choose_lock(kind, tmp_path)
    want = {"flock": LOCK_NAME, "lease": LEASE_NAME}[chosen]
    assert all(names[0] == want for names in held.values()) and set(held) == {"a", "b"}  # held while computed
    left = [p for p in tmp_path.rglob(".*")]
    # what stays: the flock kind's emptied lock files (every claimant locks the same inode)
    assert all(p.name == LOCK_NAME and p.read_text() == "" for p in left) and (chosen == "flock") == bool(left)


def test_a_bad_lock_setting_names_its_key_and_the_fix(tmp_path):
    with pytest.raises(ValueError, match=r"grid.lock='nfs': must be one of auto, flock, lease; e.g. grid.lock=auto"):
        run_cells(cells_in(tmp_path, ["a"]), lambda c, s: {}, root=tmp_path, policy=Policy(lock="nfs"))
    with pytest.raises(ValueError, match=r"grid.lease_ttl_s=0: must be a finite number of seconds > 0"):
        run_cells(cells_in(tmp_path, ["a"]), lambda c, s: {}, root=tmp_path, policy=Policy(lease_ttl_s=0))
    assert not (tmp_path / "a").exists()


@pytest.mark.parametrize("kind", ["flock", "lease"])
def test_hold_waits_for_the_claim_and_then_holds_it(tmp_path, kind):
    order = []
    with claim(tmp_path, kind=kind, ttl_s=30) as mine:
        assert mine

        def waiter():
            with locks.hold(tmp_path, kind=kind, ttl_s=30, poll_s=0.05):
                order.append("waiter holds")
                assert not _try(tmp_path, kind, 30)  # held: others are refused

        t = threading.Thread(target=waiter)
        t.start()
        time.sleep(0.3)
        order.append("first releases")
    t.join(10)
    assert order == ["first releases", "waiter holds"]
    assert dotfiles(tmp_path) == ([LOCK_NAME] if kind == "flock" else [])
