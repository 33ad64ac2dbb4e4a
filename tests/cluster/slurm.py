"""A single-node Slurm for the tests: its own munged, slurmctld and slurmd, started and stopped here.

Everything lives in one temporary folder: a fresh munge key and socket, a ``slurm.conf``, the pid
files, logs, spool and state folders. The daemons run in the foreground as child processes of the
test process, each in its own process group, on TCP ports picked free at start. When the test
process is killed, the daemons get SIGTERM from the kernel (``PR_SET_PDEATHSIG``); a daemon left over
anyway keeps its old ports and socket, so it cannot answer a new cluster. A job running at that
moment runs on to its own end (its ``slurmstepd`` is not a child of slurmd), and the killed run's
temporary folder stays: the tests' jobs end by themselves within a minute. Clients see the
cluster only through :attr:`SlurmCluster.env` (``SLURM_CONF`` pointing at this ``slurm.conf``, the
caller's other ``SLURM_*`` / ``SBATCH_*`` / ``SQUEUE_*`` ... variables removed), so a system-wide Slurm
or munge on the machine is never used nor changed.

Conventions: memory in MiB (Slurm's ``RealMemory`` unit); job ids are strings as Slurm prints them
(``"12"``, array tasks ``"12_0"``); timeouts in seconds. Debian/Ubuntu packages (Slurm 22.05 was
used here): ``make system-deps-slurm``. The daemons run as root (``SlurmUser=root``,
``SlurmdUser=root``): slurmd must be root to start jobs as their user.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, closing, contextmanager
from dataclasses import dataclass, field
from pathlib import Path

INSTALL_TARGET = "make system-deps-slurm"
DAEMONS = ("munged", "slurmctld", "slurmd")
CLIENTS = ("sbatch", "squeue", "scancel", "sinfo", "scontrol", "srun")
# the caller's variables that would redirect or change the client commands
CLIENT_ENV_PREFIXES = ("SLURM_", "SBATCH_", "SQUEUE_", "SINFO_", "SCANCEL_", "SRUN_", "SALLOC_", "SACCT_")
TERMINAL_STATES = frozenset(
    {
        "BOOT_FAIL",
        "CANCELLED",
        "COMPLETED",
        "DEADLINE",
        "FAILED",
        "NODE_FAIL",
        "OUT_OF_MEMORY",
        "PREEMPTED",
        "TIMEOUT",
    }
)
# A requeued job waits for its old credential to expire before it may start again: Slurm's default
# of 120 s is shortened for the tests (Slurm rejects values below 5 s).
CRED_EXPIRE_S = 10
# a Unix socket path longer than this does not fit sockaddr_un (108 bytes with the final NUL)
MAX_SOCKET_PATH = 107
PR_SET_PDEATHSIG = 1  # prctl(2)


def missing_reason() -> str | None:
    """Why a local cluster cannot start here (binaries missing, not root), or None when it can."""
    missing = [b for b in DAEMONS + CLIENTS if _which(b) is None]
    if missing:
        return f"Slurm binaries not found: {', '.join(missing)} (install them with `{INSTALL_TARGET}`)"
    if os.geteuid() != 0:
        return (
            "a local Slurm needs root (slurmd starts jobs as their user, munged and slurmctld run as "
            f"SlurmUser=root); run the tests as root, after `{INSTALL_TARGET}`"
        )
    return None


def real_memory_mb(meminfo: str, fraction: float = 0.5) -> int:
    """``fraction`` of ``MemTotal`` of a ``/proc/meminfo`` text, in MiB (floor, at least 1).

    >>> real_memory_mb("MemTotal:       24683584 kB\\nMemFree: 1 kB\\n")
    12052
    """
    for line in meminfo.splitlines():
        if line.startswith("MemTotal:"):
            kib = int(line.split()[1])
            return max(1, int(kib * fraction) // 1024)
    raise ValueError("no MemTotal line in the /proc/meminfo text")


def slurm_conf_text(
    *,
    root: Path,
    host: str,
    cpus: int,
    memory_mb: int,
    ctld_port: int,
    slurmd_port: int,
    munge_socket: Path,
    cluster_name: str = "local",
) -> str:
    """The ``slurm.conf`` of one node ``host`` (controller and compute node, reached on 127.0.0.1)
    with ``cpus`` CPUs and ``memory_mb`` MiB in the default partition ``debug``; every file the
    daemons write lies under ``root``, authentication goes through the munged at ``munge_socket``."""
    lines = {
        "ClusterName": cluster_name,
        "SlurmctldHost": f"{host}(127.0.0.1)",
        "SlurmctldPort": ctld_port,
        "SlurmdPort": slurmd_port,
        "AuthType": "auth/munge",
        "CredType": "cred/munge",
        "AuthInfo": f"socket={munge_socket},cred_expire={CRED_EXPIRE_S}",
        "ProctrackType": "proctrack/linuxproc",
        "TaskPlugin": "task/none",
        "SchedulerType": "sched/backfill",
        # schedule pending jobs (a requeued one, once eligible again) within seconds, not minutes
        "SchedulerParameters": "sched_interval=2,bf_interval=1",
        "SelectType": "select/cons_tres",
        "SelectTypeParameters": "CR_Core",
        "ReturnToService": 2,
        "JobRequeue": 1,
        # SIGKILL 2 s after SIGTERM (a preemption's grace time): a requeued job dies mid-cell
        "KillWait": 2,
        "MinJobAge": 600,
        "SlurmUser": "root",
        "SlurmdUser": "root",
        "MpiDefault": "none",
        "JobCompType": "jobcomp/none",
        "JobAcctGatherType": "jobacct_gather/none",
        "AccountingStorageType": "accounting_storage/none",
        "SlurmctldPidFile": root / "slurmctld.pid",
        "SlurmdPidFile": root / "slurmd.pid",
        "SlurmdSpoolDir": root / "spool",
        "StateSaveLocation": root / "state",
        "SlurmctldLogFile": root / "log" / "slurmctld.log",
        "SlurmdLogFile": root / "log" / "slurmd.log",
        "SlurmctldDebug": "info",
        "SlurmdDebug": "info",
    }
    text = "".join(f"{k}={v}\n" for k, v in lines.items())
    text += f"NodeName={host} NodeAddr=127.0.0.1 CPUs={cpus} RealMemory={memory_mb} State=UNKNOWN\n"
    text += f"PartitionName=debug Nodes={host} Default=YES MaxTime=INFINITE State=UP\n"
    return text


def client_env(conf: Path, base: dict[str, str] | None = None) -> dict[str, str]:
    """``base`` (default ``os.environ``) without the Slurm client variables, plus ``SLURM_CONF``."""
    env = {k: v for k, v in (os.environ if base is None else base).items() if not k.startswith(CLIENT_ENV_PREFIXES)}
    env["SLURM_CONF"] = str(conf)
    return env


def _which(name: str) -> str | None:
    # the daemons live in /usr/sbin, not always on a user's PATH
    return shutil.which(name) or shutil.which(name, path="/usr/sbin:/usr/local/sbin:/sbin")


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_STREAM) for _ in range(n)]
    with ExitStack() as stack:
        for s in socks:
            stack.enter_context(closing(s))
            s.bind(("", 0))
        return [s.getsockname()[1] for s in socks]


def _tail(path: Path, lines: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(none)"


@dataclass
class SlurmCluster:
    """A started cluster: its folder, ``slurm.conf``, the environment for client commands, and the
    daemon processes (name -> Popen)."""

    root: Path
    conf: Path
    env: dict[str, str]
    node: str
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)

    def run(self, cmd: Sequence[str], *, check: bool = True, timeout: float = 60) -> subprocess.CompletedProcess:
        """Run a client command against this cluster; raise with its output when it fails."""
        res = subprocess.run(list(cmd), env=self.env, capture_output=True, text=True, timeout=timeout)
        if check and res.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} exited {res.returncode}\nstdout: {res.stdout}\nstderr: {res.stderr}")
        return res

    def sbatch(self, *args: str) -> str:
        """Submit with ``sbatch --parsable ARGS``; returns the job id."""
        return self.run(["sbatch", "--parsable", *args]).stdout.strip().split(";")[0]

    def states(self, job_ids: Sequence[str]) -> dict[str, str]:
        """State of each job and array task of ``job_ids`` known to the controller (id -> state)."""
        out = self.run(["squeue", "--states=all", "--noheader", "--format=%i %T", f"--jobs={','.join(job_ids)}"])
        return dict(line.split() for line in out.stdout.splitlines() if line.strip())

    def wait_jobs(self, job_ids: Sequence[str], timeout: float = 60, poll: float = 0.5) -> dict[str, str]:
        """Wait until every job (every task of an array) of ``job_ids`` reached a terminal state;
        returns id -> state. Raises TimeoutError with the states and the daemons' logs."""
        deadline = time.monotonic() + timeout
        while True:
            states = self.states(job_ids)
            pending_arrays = [i for i in states if "[" in i]
            if states and not pending_arrays and all(s in TERMINAL_STATES for s in states.values()):
                return states
            if time.monotonic() > deadline:
                raise TimeoutError(f"jobs {list(job_ids)} not finished after {timeout} s: {states}\n{self.logs()}")
            time.sleep(poll)

    def wait_state(self, job_id: str, state: str, timeout: float = 60, poll: float = 0.5) -> None:
        """Wait until job ``job_id`` is in ``state`` (e.g. ``RUNNING``)."""
        deadline = time.monotonic() + timeout
        while (got := self.states([job_id]).get(job_id)) != state:
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} is {got}, not {state}, after {timeout} s\n{self.logs()}")
            time.sleep(poll)

    def requeue(self, job_id: str) -> None:
        """``scontrol requeue``: stop the job and put it back in the queue; it restarts from the
        start once its credential expired (``CRED_EXPIRE_S``), with ``SLURM_RESTART_COUNT`` raised."""
        self.run(["scontrol", "requeue", job_id])

    def cancel(self, job_ids: Sequence[str]) -> None:
        """``scancel`` the given jobs."""
        if job_ids:
            self.run(["scancel", *job_ids])

    def logs(self, lines: int = 30) -> str:
        """The last lines of every daemon's log and output, and which daemons exited."""
        parts = []
        for name, proc in self.procs.items():
            rc = proc.poll()
            parts.append(f"--- {name} (pid {proc.pid}, {'running' if rc is None else f'exited {rc}'})")
            # a running daemon's log file (its output duplicates it), or its output (errors before
            # its log file was opened, munged's log in the foreground)
            log = self.root / "log" / f"{name}.log"
            parts.append(_tail(log if rc is None and log.exists() else log.with_suffix(".out"), lines))
        return "\n".join(parts)

    def _spawn(self, name: str, cmd: list[str]) -> None:
        log = self.root / "log" / f"{name}.out"
        with open(log, "ab") as out:
            self.procs[name] = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=self.env,
                start_new_session=True,
                preexec_fn=_die_with_parent,
            )

    def _wait(self, what: str, ready, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not ready():
            dead = [n for n, p in self.procs.items() if p.poll() is not None]
            if dead or time.monotonic() > deadline:
                why = f"{', '.join(dead)} exited" if dead else f"not after {timeout} s"
                raise RuntimeError(f"local Slurm: {what}: {why}\n{self.logs()}")
            time.sleep(0.25)

    def _node_idle(self) -> bool:
        res = self.run(["sinfo", "--noheader", "--format=%t", f"--nodes={self.node}"], check=False, timeout=10)
        return res.returncode == 0 and res.stdout.strip() == "idle"

    def _controller_up(self) -> bool:
        return self.run(["scontrol", "ping"], check=False, timeout=10).returncode == 0

    def stop(self, timeout: float = 10) -> None:
        """Cancel every job, then SIGTERM each daemon's process group (slurmd, slurmctld, munged),
        SIGKILL after ``timeout`` s."""
        if self.procs.get("slurmctld") and self.procs["slurmctld"].poll() is None:
            res = self.run(["squeue", "--noheader", "--format=%A"], check=False, timeout=10)
            ids = res.stdout.split() if res.returncode == 0 else []
            if ids:
                self.run(["scancel", *ids], check=False, timeout=10)
                deadline = time.monotonic() + timeout
                while time.monotonic() < deadline:
                    res = self.run(["squeue", "--noheader", "--format=%A"], check=False, timeout=10)
                    if res.returncode != 0 or not res.stdout.split():
                        break
                    time.sleep(0.25)
        for name in reversed(list(self.procs)):
            proc = self.procs[name]
            if proc.poll() is not None:
                continue
            _signal_group(proc, signal.SIGTERM)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                _signal_group(proc, signal.SIGKILL)
                proc.wait(timeout)


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM when the process that started it dies (a killed test run
    leaves no daemon behind). Linux only; elsewhere a no-op."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass


def _signal_group(proc: subprocess.Popen, sig: int) -> None:
    # each daemon leads its own process group (start_new_session): the group id is its pid
    try:
        os.killpg(proc.pid, sig)
    except ProcessLookupError:
        pass


@contextmanager
def local_slurm(timeout: float = 60, memory_fraction: float = 0.5) -> Iterator[SlurmCluster]:
    """Start munged, slurmctld and slurmd in a new temporary folder, wait until the node is idle,
    yield the :class:`SlurmCluster`; stop the daemons and remove the folder afterwards."""
    reason = missing_reason()
    if reason:
        raise RuntimeError(reason)
    root = Path(tempfile.mkdtemp(prefix="slurm-"))
    # searchable, not listable, by others: munged wants every folder above its socket searchable
    root.chmod(0o711)
    try:
        for sub in ("spool", "state", "log"):
            (root / sub).mkdir(mode=0o700)
        # munged wants its socket folder searchable by all (the temporary folder above stays private)
        (root / "munge").mkdir(mode=0o755)
        munge_socket = root / "munge" / "munge.socket"
        if len(str(munge_socket)) > MAX_SOCKET_PATH:
            raise RuntimeError(
                f"munge socket path {munge_socket} is longer than {MAX_SOCKET_PATH} bytes: set TMPDIR to a shorter folder"
            )
        key = root / "munge" / "munge.key"
        key.write_bytes(os.urandom(1024))
        key.chmod(0o400)
        node = socket.gethostname().split(".")[0]
        ctld_port, slurmd_port = _free_ports(2)
        conf = root / "slurm.conf"
        conf.write_text(
            slurm_conf_text(
                root=root,
                host=node,
                cpus=os.cpu_count() or 1,
                memory_mb=real_memory_mb(Path("/proc/meminfo").read_text(), memory_fraction),
                ctld_port=ctld_port,
                slurmd_port=slurmd_port,
                munge_socket=munge_socket,
            )
        )
        cluster = SlurmCluster(root=root, conf=conf, env=client_env(conf), node=node)
        try:
            cluster._spawn(
                "munged",
                [
                    _which("munged"),
                    "--foreground",
                    "--force",
                    f"--socket={munge_socket}",
                    f"--key-file={key}",
                    f"--log-file={root / 'log' / 'munged.log'}",
                    f"--pid-file={root / 'munge' / 'munged.pid'}",
                    f"--seed-file={root / 'munge' / 'munged.seed'}",
                ],
            )
            cluster._wait("munged socket", munge_socket.exists, timeout)
            cluster._spawn("slurmctld", [_which("slurmctld"), "-D", "-c", "-f", str(conf)])
            cluster._wait("slurmctld answering `scontrol ping`", cluster._controller_up, timeout)
            cluster._spawn("slurmd", [_which("slurmd"), "-D", "-f", str(conf), "-N", node])
            cluster._wait(f"node {node} idle in sinfo", cluster._node_idle, timeout)
            yield cluster
        finally:
            cluster.stop()
    finally:
        shutil.rmtree(root, ignore_errors=True)
