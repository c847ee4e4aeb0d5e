"""A local Ray cluster on loopback: a head and N worker nodes, each its own `ray start`, every
address 127.0.0.1, Ray's token authentication on, its own temp dir; stopped by its own process
groups only (never `ray stop`, which stops every Ray on the machine).

Ray 2.60 rewrites 127.0.0.1 to the machine's address (`resolve_ip_for_localhost`) in two places:
the node address of `ray start`, and the cluster address a worker node or driver joins. Given
127.0.0.1 literally, its servers bind 127.0.0.1 only (gcs_server, raylet and the agents test for
that string); given the rewritten address they bind 0.0.0.0. So:
- the head and the driver run with RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0, under which Ray's own
  address lookup answers 127.0.0.1 (on Linux that variable changes nothing else for them);
- a worker node cannot (under it `ray start --address` refuses to join), so it runs Ray's own
  `ray start` entry point with that one rewrite disabled for 127.0.0.1 (WORKER_START below).
Used by `bench scale --cluster` and tests/test_ray_cluster.py.
"""
from __future__ import annotations

import os
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LOOPBACK = "127.0.0.1"
REPO = Path(__file__).resolve().parent.parent

# `ray start` for a worker node that keeps 127.0.0.1 as given (see the module docstring).
WORKER_START = """
import sys
import ray._private.services as services
real = services.resolve_ip_for_localhost
services.resolve_ip_for_localhost = lambda host: host if host == "127.0.0.1" else real(host)
from ray.scripts.scripts import main
sys.argv = ["ray", *sys.argv[1:]]
main()
"""


class ClusterError(RuntimeError):
    """The local cluster did not start."""


class LocalCluster:
    """`with LocalCluster(workers=2) as c:` ... `c.address`, `c.driver_env()`, `c.kill_worker(0)`."""

    def __init__(self, workers: int = 2, cpus_per_worker: int = 1, timeout: float = 120.0):
        self.workers, self.cpus, self.timeout = workers, cpus_per_worker, timeout
        self.token = secrets.token_hex(32)
        # Short: Ray's Unix sockets live under it (a path of at most 107 bytes).
        self.temp = Path(tempfile.mkdtemp(prefix="apray-", dir="/tmp"))
        self.groups: list[int] = []  # process group of each node, head first
        self.address = ""

    def _env(self, head_or_driver: bool) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
        env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=self.token, RAY_USAGE_STATS_ENABLED="0",
                   PYTHONPATH=os.pathsep.join(filter(None, (str(REPO), env.get("PYTHONPATH")))))
        if head_or_driver:
            env["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
        return env

    def driver_env(self) -> dict[str, str]:
        """The environment of a driver process (`asset-bake --executor ray`) for this cluster."""
        return {**self._env(True), "RAY_ADDRESS": self.address}

    def _start(self, cmd: list[str], env: dict[str, str], what: str) -> None:
        log = self.temp / f"{what}.log"
        with open(log, "wb") as out:
            # Its own session: the node's daemons keep this process group, so stop() ends
            # exactly this cluster's processes.
            proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT,
                                    start_new_session=True, cwd=REPO)
        self.groups.append(proc.pid)
        try:
            code = proc.wait(self.timeout)
        except subprocess.TimeoutExpired:
            code = -1
        if code != 0:
            raise ClusterError(f"ray start ({what}) failed ({code}): {log.read_text()[-1500:]}")

    def start(self) -> "LocalCluster":
        ray_bin = str(Path(sys.executable).with_name("ray"))
        common = ["--node-ip-address", LOOPBACK, "--temp-dir", str(self.temp / "ray"),
                  "--disable-usage-stats"]
        try:
            # The head runs no tasks (0 CPUs): throughput is the worker nodes'.
            self._start([ray_bin, "start", "--head", "--port", "0", "--num-cpus", "0",
                         "--include-dashboard", "false",
                         "--ray-client-server-port", str(free_port()), *common], self._env(True), "head")
            self.address = (self.temp / "ray" / "ray_current_cluster").read_text().strip()
            if not self.address.startswith(LOOPBACK + ":"):
                raise ClusterError(f"the head came up at {self.address}, not on {LOOPBACK}")
            for i in range(self.workers):
                self.add_worker(i, common)
            self.wait_nodes(self.workers + 1)
        except BaseException:
            self.stop()
            raise
        return self

    def add_worker(self, i: int, common: list[str] | None = None) -> None:
        common = common or ["--node-ip-address", LOOPBACK, "--temp-dir", str(self.temp / "ray"),
                            "--disable-usage-stats"]
        self._start([sys.executable, "-c", WORKER_START, "start", "--address", self.address,
                     "--num-cpus", str(self.cpus), *common], self._env(False), f"worker{i}")

    def alive_nodes(self) -> int:
        """Nodes the GCS counts alive (asked in a fresh process: this one may hold another Ray)."""
        code = ("import ray; ray.init(address='auto', logging_level='ERROR'); "
                "print('alive-nodes', sum(n['Alive'] for n in ray.nodes()))")
        out = subprocess.run([sys.executable, "-c", code], env=self.driver_env(), capture_output=True,
                             text=True, timeout=self.timeout, cwd=REPO)
        if out.returncode:
            raise ClusterError(f"cannot ask the cluster at {self.address}: {out.stderr[-800:]}")
        # Ray may print its own notices on stdout (one ends "...workload."): read the marked line
        counts = [line.split()[1] for line in out.stdout.splitlines() if line.startswith("alive-nodes ")]
        if not counts:
            raise ClusterError(f"the cluster at {self.address} gave no node count: {out.stdout[-800:]}")
        return int(counts[-1])

    def wait_nodes(self, n: int) -> None:
        end = time.monotonic() + self.timeout
        while (alive := self.alive_nodes()) != n:
            if time.monotonic() > end:
                raise ClusterError(f"{alive} nodes alive, expected {n}")
            time.sleep(1)

    def raylet_pid(self, worker: int) -> int:
        """The raylet of worker node `worker` (0-based), found in that node's process group."""
        group = self.groups[1 + worker]
        for pid in os.listdir("/proc"):
            if pid.isdigit():
                try:
                    if os.getpgid(int(pid)) == group and Path(f"/proc/{pid}/comm").read_text().strip() == "raylet":
                        return int(pid)
                except (OSError, ProcessLookupError):
                    continue
        raise ClusterError(f"no raylet for worker node {worker}")

    def kill_worker(self, worker: int) -> int:
        """SIGKILL worker node `worker`'s raylet (its task workers die with it); returns its pid."""
        pid = self.raylet_pid(worker)
        os.kill(pid, signal.SIGKILL)
        return pid

    def listening(self) -> list[str]:
        """Local addresses this cluster's processes listen on (from `ss -ltnp`)."""
        pids = {int(p) for p in os.listdir("/proc") if p.isdigit() and _pgid(int(p)) in self.groups}
        out = subprocess.run(["ss", "-ltnpH"], capture_output=True, text=True).stdout
        found = []
        for line in out.splitlines():
            if any(f"pid={p}," in line for p in pids):
                found.append(line.split()[3])
        return found

    def stop(self) -> None:
        """End this cluster's process groups (TERM, then KILL), and remove its temp dir."""
        for group in self.groups:
            try:
                os.killpg(group, signal.SIGTERM)
            except ProcessLookupError:
                pass
        self._wait_gone(10)
        for group in self.groups:
            try:
                os.killpg(group, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self._wait_gone(10)  # a KILL is not instant on a loaded host: return once they are gone
        self.groups = []
        shutil.rmtree(self.temp, ignore_errors=True)

    def _wait_gone(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and any(_group_alive(g) for g in self.groups):
            time.sleep(0.2)

    def __enter__(self) -> "LocalCluster":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


def _pgid(pid: int) -> int | None:
    try:
        return os.getpgid(pid)
    except OSError:
        return None


def _group_alive(group: int) -> bool:
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return False
    return any(_pgid(int(p)) == group and not _zombie(int(p)) for p in os.listdir("/proc") if p.isdigit())


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True
