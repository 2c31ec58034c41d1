"""A multi-node Ray cluster on one machine, for checking the Ray backend before renting a real one.

:class:`LocalRayCluster` starts a head node (no CPUs: it only schedules) and worker nodes with ``ray start``, each a
separate set of processes with its own ``--temp-dir`` and its own scratch folder (``TMPDIR``, where its jobs write
their artefacts before sending them back), and offers each worker a custom resource (default ``meshadv_worker``) so
that jobs can be pinned to worker nodes (``RayBackend(resources={"meshadv_worker": 1})``). A worker node can be
killed (every process of its temp dir, SIGKILL: what a lost machine looks like to the cluster) to check that the
sweep retries and loses nothing. ``add_worker(hidden=[folder])`` starts a worker node in a mount namespace of its own
in which each of those folders is an empty, read-only tmpfs: a worker that cannot see the driver's output folder, as
on a cluster without a shared file system (Linux, where ``unshare --mount`` is permitted:
:func:`can_hide_folders`).

Example:
    >>> with LocalRayCluster(root="/tmp/cluster") as cluster:                 # doctest: +SKIP
    ...     cluster.add_worker(); cluster.add_worker()
    ...     ray.init(address=cluster.address)
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Union

__all__ = ["LocalRayCluster", "WORKER_RESOURCE", "can_hide_folders", "write_token"]

#: Runs its arguments as a command after mounting an empty read-only tmpfs on each folder named in ``$HIDE``
#: (newline-separated), inside the private mount namespace ``unshare --mount --propagation private`` gives it.
_HIDING_SHELL = ('printf "%s\n" "$HIDE" | while IFS= read -r d; do [ -z "$d" ] || '
                 'mount -t tmpfs -o size=64k,mode=0555,ro meshadv-hidden "$d" || exit 90; done && exec "$@"')


@functools.lru_cache(maxsize=None)
def can_hide_folders() -> bool:
    """Whether this machine lets a process mount over a folder in a private mount namespace (``unshare --mount``,
    Linux; root or a user namespace), which :meth:`LocalRayCluster.add_worker` needs for ``hidden`` (tried once
    per process: a property of the machine)."""
    if shutil.which("unshare") is None:
        return False
    with tempfile.TemporaryDirectory() as folder:
        marker = Path(folder) / "visible"
        marker.write_text("x")
        try:
            proc = subprocess.run(["unshare", "--mount", "--propagation", "private", "sh", "-c",
                                   _HIDING_SHELL + ' && test ! -e "$0"', str(marker)],
                                  env={**os.environ, "HIDE": folder}, capture_output=True, timeout=30)
        except (OSError, subprocess.SubprocessError):
            return False
        return proc.returncode == 0 and marker.exists()

#: The custom resource worker nodes offer (one unit per CPU).
WORKER_RESOURCE = "meshadv_worker"


def write_token(path: Union[str, Path]) -> Path:
    """Write a fresh random authentication token for a local cluster to ``path`` (owner-only) and return it."""
    import secrets

    from meshadv.util.atomic import write_bytes_atomic

    token = Path(path)
    token.parent.mkdir(parents=True, exist_ok=True)
    # atomic and owner-only from the first byte (the temporary file is 0600; no moment readable by others)
    return write_bytes_atomic(token, secrets.token_hex(32).encode("ascii"), mode=0o600)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _pids_using(marker: str) -> List[int]:
    """Processes whose command line contains ``marker`` (a temp dir unique to one node), and their descendants
    (Ray's worker processes rename themselves ``ray::...`` but are children of their node's raylet)."""
    found, parents = set(), {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        parents[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
        if marker in cmd:
            found.add(int(entry.name))
    grew = True
    while grew:
        children = {pid for pid, ppid in parents.items() if ppid in found} - found
        found |= children
        grew = bool(children)
    found.discard(os.getpid())
    return sorted(found)


class LocalRayCluster:
    """A head and worker nodes started with ``ray start`` as separate processes (see the module docstring).

    Args:
        root: folder for the nodes' temp dirs, scratch folders and logs (short paths: Ray's socket paths are
            limited to about 100 characters).
        env: extra environment of every node and of :meth:`driver_env`. The cluster authenticates with a token of
            its own (``RAY_AUTH_MODE=token``, ``RAY_AUTH_TOKEN_PATH=<root>/auth_token``, written here unless the
            environment names one), so it neither needs nor uses a token of the user's (``~/.ray/auth_token``).
            Ray reads ``RAY_AUTH_MODE`` when it is first imported: a driver process must have :meth:`driver_env` in
            its environment before it imports ray.

    Raises:
        RuntimeError: ``ray start`` failed (its output in the message).
    """

    def __init__(self, root: Union[str, Path], env: Optional[Dict[str, str]] = None) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_USAGE_STATS_ENABLED": "0", **(env or {})}
        if not self.env.get("RAY_AUTH_TOKEN_PATH"):
            self.env["RAY_AUTH_TOKEN_PATH"] = str(write_token(self.root / "auth_token"))
        self.port = _free_port()
        self.workers: Dict[str, Path] = {}
        self._head_dir = self.root / "head"
        self._run(["--head", "--port", str(self.port), "--num-cpus", "0", "--include-dashboard", "false",
                   "--temp-dir", str(self._head_dir)], self._head_dir, self.env)
        self.address = f"{self._node_ip()}:{self.port}"

    def _node_ip(self) -> str:
        info = self._head_dir / "ray_current_cluster"
        if info.is_file():
            text = info.read_text().strip()
            if ":" in text:
                return text.rsplit(":", 1)[0]
        return socket.gethostbyname(socket.gethostname())

    def _run(self, args: List[str], temp_dir: Path, env: Dict[str, str], prefix: Sequence[str] = ()) -> None:
        temp_dir.mkdir(parents=True, exist_ok=True)
        proc = subprocess.run([*prefix, "ray", "start", "--disable-usage-stats", *args], env=env,
                              capture_output=True, text=True, timeout=300)
        (temp_dir.parent / f"{temp_dir.name}.start.log").write_text(proc.stdout + proc.stderr)
        if proc.returncode != 0:
            raise RuntimeError(f"ray start {' '.join(args)} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")

    def add_worker(self, name: Optional[str] = None, *, cpus: int = 1, hidden: Sequence[Union[str, Path]] = ()) -> str:
        """Start a worker node with ``cpus`` CPUs and as many units of :data:`WORKER_RESOURCE`; return its name.

        Args:
            name: the node's name (default ``w1``, ``w2``, ...).
            cpus: its CPUs.
            hidden: existing folders the node's processes must not see (each becomes an empty read-only tmpfs in
                the node's own mount namespace; the rest of the file system is shared).

        Raises:
            ValueError: a ``hidden`` entry is not an existing folder, or this machine cannot hide folders
                (:func:`can_hide_folders`).
        """
        name = name or f"w{len(self.workers) + 1}"
        temp_dir = self.root / name
        scratch = self.root / f"{name}_scratch"
        scratch.mkdir(parents=True, exist_ok=True)
        env = {**self.env, "TMPDIR": str(scratch)}
        prefix: List[str] = []
        if hidden:
            folders = [Path(h).resolve() for h in hidden]
            missing = [str(f) for f in folders if not f.is_dir()]
            if missing:
                raise ValueError(f"hidden must name existing folders, got {missing}")
            if not can_hide_folders():
                raise ValueError("hidden: this machine does not permit `unshare --mount` (a private mount "
                                 "namespace), so a worker cannot be kept from seeing a folder")
            env["HIDE"] = "\n".join(str(f) for f in folders)
            prefix = ["unshare", "--mount", "--propagation", "private", "sh", "-c", _HIDING_SHELL, "hide"]
        self._run(["--address", self.address, "--num-cpus", str(cpus), "--temp-dir", str(temp_dir),
                   "--resources", json.dumps({WORKER_RESOURCE: cpus})], temp_dir, env, prefix)
        self.workers[name] = temp_dir
        return name

    def scratch(self, name: str) -> Path:
        """The scratch folder (``TMPDIR``) of worker node ``name``: where its jobs run."""
        return self.root / f"{name}_scratch"

    def kill_worker(self, name: str) -> int:
        """SIGKILL every process of worker node ``name`` (a lost machine); return how many were killed."""
        pids = _pids_using(f"{self.workers.pop(name)}/")
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        return len(pids)

    def driver_env(self) -> Dict[str, str]:
        """Environment variables a driver process needs to join (``RAY_AUTH_MODE``, ``RAY_AUTH_TOKEN_PATH``)."""
        return {"RAY_AUTH_MODE": self.env["RAY_AUTH_MODE"], "RAY_AUTH_TOKEN_PATH": self.env["RAY_AUTH_TOKEN_PATH"]}

    def shutdown(self) -> None:
        """Kill every node of this cluster (and nothing else: only processes of its own temp dirs)."""
        for name in list(self.workers):
            self.kill_worker(name)
        for _ in range(3):
            pids = _pids_using(f"{self._head_dir}/")
            if not pids:
                break
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGTERM if _ == 0 else signal.SIGKILL)
                except ProcessLookupError:
                    pass
            time.sleep(1.0)

    def __enter__(self) -> "LocalRayCluster":
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()
