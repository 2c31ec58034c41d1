"""The Ray backend on a local multi-node cluster without a shared file system: throughput and a lost node.

A head node (no CPUs) and worker nodes are started with ``ray start`` as separate processes, each with its own temp
dir and scratch folder (``tests/ray_local.py``); jobs are pinned to worker nodes by a
custom resource, run in their node's scratch folder and send their artefacts back through Ray; the driver alone
writes the artefact folders and the database.

1. Throughput: jobs/s of tiny jobs (``mesh_probe_job``: an icosphere "attack" of ``--job-seconds`` that writes two PLY
   meshes and two PNGs and returns their bytes) with 1, then 2 worker nodes of 1 CPU each; the overhead per job is
   the wall time beyond ``jobs x job_seconds / nodes``.
2. A lost node: 2 worker nodes run slower probe jobs; one node is killed (SIGKILL of all its processes) mid-sweep; the
   sweep records the lost attempts, retries them on the surviving node, and ends with every job done once, every
   artefact folder complete, and no job having run in (or written to) the driver's folder.

    python benchmarks/ray_cluster_bench.py --jobs 40 --kill-jobs 12 --out /tmp/raybench

Prints a Markdown summary and writes ``<out>/ray_cluster_bench.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Dict, List

from meshadv.experiments import RayBackend, ResultStore, job_id, run_sweep

#: The local Ray cluster and the probe jobs are test tooling (tests/); the cluster's nodes import the probe jobs too.
_TESTS = str(Path(__file__).resolve().parents[1] / "tests")
sys.path.insert(0, _TESTS)
os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (_TESTS, os.environ.get("PYTHONPATH", "")) if p)

from ray_local import WORKER_RESOURCE, LocalRayCluster, can_hide_folders, write_token  # noqa: E402


def _connect(address: str, workers: int, timeout: float = 120.0) -> None:
    """Join the cluster and wait until ``workers`` units of the worker resource are registered."""
    import ray

    if not ray.is_initialized():
        ray.init(address=address, log_to_driver=False)
    deadline = time.time() + timeout
    while ray.cluster_resources().get(WORKER_RESOURCE, 0) < workers:
        if time.time() > deadline:
            raise RuntimeError(f"only {ray.cluster_resources().get(WORKER_RESOURCE, 0)} of {workers} workers joined")
        time.sleep(0.5)


def _sweep(address: str, specs: List[Dict[str, Any]], job: str, out: Path, **kw: Any) -> Dict[str, Any]:
    backend = RayBackend(resources={WORKER_RESOURCE: 1})
    start = time.perf_counter()
    with ResultStore(out / "results.db") as store:
        summary = run_sweep(store, specs, job, out_root=out, backend=backend, max_attempts=3, progress=False, **kw)
        rows = store.rows()
    seconds = time.perf_counter() - start
    return {"summary": summary.__dict__, "seconds": seconds, "jobs_per_s": len(specs) / seconds,
            "capacity": backend.capacity, "rows": rows}


def _check_no_shared_folder(rows: List[Any], out: Path, scratch: List[Path]) -> Dict[str, Any]:
    """Every done job's folder is complete in the driver's folder, and every job ran in a worker's scratch folder."""
    ran_in = []
    for row in rows:
        folder = Path(row.out_dir)
        assert folder.is_dir() and str(folder).startswith(str(out)), row.out_dir
        for name in ("benign.ply", "adversarial.ply", "benign_v0.png", "after_v0.png"):
            assert (folder / name).is_file(), (row.job_id, name)
        worker_dir = row.record["job_dir"]
        assert not worker_dir.startswith(str(out)), worker_dir  # never the driver's folder
        assert any(worker_dir.startswith(str(s)) for s in scratch), worker_dir
        ran_in.append(next(s.name for s in scratch if worker_dir.startswith(str(s))))
    return {n: ran_in.count(n) for n in sorted(set(ran_in))}


def throughput(root: Path, jobs: int, job_seconds: float) -> Dict[str, Any]:
    """Jobs/s with 1 and 2 worker nodes (1 CPU each), after a warm-up sweep that starts each node's worker."""
    import ray

    out: Dict[str, Any] = {}
    with LocalRayCluster(root / "cluster_tp") as cluster:
        for nodes in (1, 2):
            cluster.add_worker()
            _connect(cluster.address, nodes)
            warm = [{"warm": i, "nodes": nodes, "sleep": job_seconds, "source_class": "chair", "target": "sofa"}
                    for i in range(2 * nodes)]
            _sweep(cluster.address, warm, "probe_jobs:mesh_probe_job", root / f"warm{nodes}")
            specs = [{"probe": "mesh", "seed": i, "nodes": nodes, "sleep": job_seconds, "source_class": "chair",
                      "target": "sofa"} for i in range(jobs)]
            folder = root / f"driver_tp{nodes}"
            res = _sweep(cluster.address, specs, "probe_jobs:mesh_probe_job", folder)
            where = _check_no_shared_folder(res.pop("rows"), folder,
                                            [cluster.scratch(n) for n in cluster.workers])
            overhead = (res["seconds"] - jobs * job_seconds / nodes) / jobs * nodes
            out[f"{nodes}_nodes"] = {**res, "jobs_by_node": where, "overhead_s_per_job": overhead}
        ray.shutdown()
    return out


def lost_node(root: Path, jobs: int, sleep: float) -> Dict[str, Any]:
    """Kill one of two worker nodes mid-sweep; the sweep must retry and lose nothing."""
    import ray

    import threading

    folder = root / "driver_kill"
    folder.mkdir(parents=True)
    sentinel = folder / "driver_only.txt"  # in the driver's folder: a job that can see the folder sees this file
    sentinel.write_text("written by the driver before the workers start\n")
    # where the machine permits it, the workers run in mount namespaces of their own in which the driver's folder
    # is an empty tmpfs: they cannot see it at all, as on a cluster without a shared file system
    hidden = [folder] if can_hide_folders() else []
    with LocalRayCluster(root / "cluster_kill") as cluster:
        w1, w2 = cluster.add_worker(hidden=hidden), cluster.add_worker(hidden=hidden)
        scratch = [cluster.scratch(w1), cluster.scratch(w2)]
        _connect(cluster.address, 2)
        specs = [{"probe": "mesh", "seed": i, "sleep": sleep, "source_class": "chair", "target": "sofa",
                  "look_for": str(sentinel)} for i in range(jobs)]
        killed: Dict[str, Any] = {}

        def kill() -> None:
            killed.update(node=w1, processes=cluster.kill_worker(w1), at=time.time())

        def on_outcome(jid: str, ok: bool) -> None:
            if not killed and "timer" not in killed:  # half-way through the next jobs, both nodes are busy
                killed["timer"] = threading.Timer(sleep / 2, kill)
                killed["timer"].start()

        res = _sweep(cluster.address, specs, "probe_jobs:mesh_probe_job", folder,
                     on_outcome=on_outcome)
        rows = res.pop("rows")
        killed.pop("timer", None)
        ray.shutdown()
    done = [r for r in rows if r.state == "done"]
    retried = [r for r in done if r.attempts > 1]
    assert len(done) == jobs and res["summary"]["failed"] == 0, res
    assert {r.job_id for r in rows} == {job_id(s) for s in specs}
    errors = [r.error.splitlines()[-1][:200] for r in retried if r.error]
    where = _check_no_shared_folder(done, folder, scratch)
    saw = sum(bool(r.record.get("saw")) for r in done)
    if hidden:
        assert saw == 0, f"{saw} job(s) saw the driver's folder from a worker that should not see it"
    isolation = {"driver_folder_hidden_from_workers": bool(hidden), "jobs_that_saw_it": saw,
                 "how": "mount namespace per worker node, the driver's folder an empty tmpfs" if hidden else
                 "none: this machine does not permit unshare --mount; the folder was visible, unused"}
    return {**res, "killed": killed, "retried_jobs": len(retried), "retry_errors": errors, "jobs_by_node": where,
            "isolation": isolation}


def main(argv: List[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--jobs", type=int, default=40, help="tiny jobs per throughput run")
    parser.add_argument("--kill-jobs", type=int, default=12, help="jobs of the lost-node run")
    parser.add_argument("--sleep", type=float, default=2.0, help="seconds per job of the lost-node run")
    parser.add_argument("--job-seconds", type=float, default=0.5, help="seconds per job of the throughput runs")
    parser.add_argument("--out", type=Path, default=Path("/tmp/meshadv-raybench"))
    parser.add_argument("--skip-throughput", action="store_true", help="only the lost-node run")
    args = parser.parse_args(argv)
    if args.out.exists():
        shutil.rmtree(args.out)
    args.out.mkdir(parents=True)
    # the clusters' own token, in the environment before ray is first imported (it reads the mode then)
    os.environ["RAY_AUTH_MODE"] = "token"
    os.environ["RAY_AUTH_TOKEN_PATH"] = str(write_token(args.out / "auth_token"))
    t0 = time.time()
    result = {"throughput": {} if args.skip_throughput else throughput(args.out, args.jobs, args.job_seconds),
              "lost_node": lost_node(args.out, args.kill_jobs, args.sleep)}
    result["total_seconds"] = time.time() - t0
    (args.out / "ray_cluster_bench.json").write_text(json.dumps(result, indent=2, default=str))
    print(f"| worker nodes (1 CPU each) | jobs of {args.job_seconds:g} s | seconds | jobs/s | overhead per job (s) "
          "| jobs by node |")
    print("|---|---|---|---|---|---|")
    for key, run in result["throughput"].items():
        print(f"| {key.split('_')[0]} | {run['summary']['total']} | {run['seconds']:.1f} | {run['jobs_per_s']:.2f} | "
              f"{run['overhead_s_per_job']:.3f} | {run['jobs_by_node']} |")
    lost = result["lost_node"]
    print(f"\nlost node: killed {lost['killed']['node']} ({lost['killed']['processes']} processes) half a job after "
          f"the first result; {lost['summary']['done']}/{lost['summary']['total']} done, "
          f"{lost['summary']['failed']} failed, "
          f"{lost['retried_jobs']} job(s) retried on the surviving node; jobs by node {lost['jobs_by_node']}; "
          f"{lost['seconds']:.1f} s")
    print(f"isolation: {lost['isolation']}")
    for err in lost["retry_errors"]:
        print(f"  lost attempt: {err}")
    print(f"total {result['total_seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
