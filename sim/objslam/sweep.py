"""Run many episodes in parallel; shared by the benchmark and the ablations.

Each job is (scene file, strategy, seed, config overlays, --set overrides); each episode writes its
own run folder. Results come back as the episode's ``metrics.json`` content plus ``run_dir``, or
``{"error": ...}`` for a failed episode (the sweep goes on). Episodes are independent and seeded,
so the numbers do not depend on the number of workers, their order or the backend.

Backends:

- ``pool`` (default): a local process pool of ``workers`` processes.
- ``ray``: every episode is a Ray task (``num_cpus=1``). Without an address a local Ray instance is
  started with ``workers`` CPUs and shut down afterwards; with ``address`` (``ray://host:10001`` or
  ``host:6379``) the tasks go to that cluster. Each task runs in the driver's working directory
  when it exists on the node (so run folders land where the pool would put them) and gets this
  checkout's ``sim/`` and ``experiments/`` on ``PYTHONPATH``; on a multi-node cluster every node
  needs the same checkout (and the built ``objslam`` package) at the same path. Ray is optional:
  ``pip install "ray==2.60.*"`` (``make setup`` installs it).
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

BACKENDS = ("pool", "ray")

REPO = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Job:
    """One episode of a sweep."""

    scene: str
    strategy: str
    seed: int
    overlays: tuple[str, ...] = ()
    overrides: tuple[str, ...] = ()
    tag: dict[str, Any] = field(default_factory=dict)


def run_job(job: Job) -> dict[str, Any]:
    """Run one episode (in a worker process)."""
    from objslam.config import load_run_config
    from objslam.episode import run_episode

    sets = [*job.overrides, f'scene="{job.scene}"', f"seed={job.seed}"]
    base = {"scene": Path(job.scene).stem, "strategy": job.strategy, "seed": job.seed, **job.tag}
    try:
        cfg = load_run_config(overlays=list(job.overlays), overrides=sets, strategy=job.strategy)
        result = run_episode(cfg, progress=False)
    except Exception as e:  # noqa: BLE001 - one failed episode must not stop the sweep
        return {**base, "error": f"{type(e).__name__}: {e}"}
    run_dir = result.run_dir
    rel = run_dir.relative_to(REPO) if run_dir.is_relative_to(REPO) else run_dir
    return {**base, **result.metrics, **job.tag, "run_dir": str(rel)}


def run_job_in(job: Job, cwd: str) -> dict[str, Any]:
    """``run_job`` in ``cwd`` when that folder exists here (a Ray task on the driver's machine)."""
    if os.path.isdir(cwd):
        os.chdir(cwd)
    return run_job(job)


def _pool_results(jobs: list[Job], workers: int) -> Iterator[tuple[int, dict[str, Any]]]:
    # Spawned, not forked: a fork of a process that already runs SAPIEN's renderer or the core's
    # threads can deadlock in the child (seen when a sweep runs after other episodes in-process).
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=max(1, workers), mp_context=ctx) as pool:
        futures = {pool.submit(run_job, j): i for i, j in enumerate(jobs)}
        for f in as_completed(futures):
            yield futures[f], f.result()


def _ray_results(jobs: list[Job], workers: int, address: str | None) -> Iterator[tuple[int, dict[str, Any]]]:
    try:
        import ray
    except ImportError as e:
        raise RuntimeError('backend "ray" needs the ray package: pip install "ray==2.60.*"') from e
    path = [str(REPO / "experiments"), str(REPO / "sim"), os.environ.get("PYTHONPATH", "")]
    runtime_env = {"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in path if p)}}
    if address:
        ray.init(address=address, runtime_env=runtime_env, log_to_driver=False)
    else:
        ray.init(num_cpus=max(1, workers), include_dashboard=False, runtime_env=runtime_env, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1)(run_job_in)
        cwd = os.getcwd()
        refs = {task.remote(j, cwd): i for i, j in enumerate(jobs)}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield refs[done[0]], ray.get(done[0])
    finally:
        ray.shutdown()


def run_sweep(
    jobs: list[Job],
    workers: int = 2,
    label: str = "episode",
    backend: str = "pool",
    address: str | None = None,
    on_result: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run jobs on ``backend`` (see the module docs) with a progress bar; results in job order.
    ``on_result`` is called with each result as it arrives (to keep what finished if the sweep is
    interrupted)."""
    from tqdm import tqdm

    if backend not in BACKENDS:
        raise ValueError(f"backend: {backend!r} is not one of {', '.join(BACKENDS)}")
    if address and backend != "ray":
        raise ValueError("address: only the ray backend takes a cluster address")
    stream = _ray_results(jobs, workers, address) if backend == "ray" else _pool_results(jobs, workers)
    results: list[dict[str, Any] | None] = [None] * len(jobs)
    with tqdm(total=len(jobs), unit=label) as bar:
        for i, r in stream:
            results[i] = r
            if on_result is not None:
                on_result(r)
            status = "FAILED" if "error" in r else f"iou3d {r['mean']['iou3d']:.3f}"
            bar.set_postfix_str(f"{r['strategy']} {r['scene']} {status}")
            bar.update(1)
    return [r for r in results if r is not None]


def scene_files() -> list[str]:
    """The benchmark scenes, relative to the repository root."""
    return [str(p.relative_to(REPO)) for p in sorted((REPO / "scenes").glob("scene*.toml"))]
