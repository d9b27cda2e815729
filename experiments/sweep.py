"""Run many episodes in parallel worker processes; shared by the benchmark and the ablations.

Each job is (scene file, strategy, seed, config overlays, --set overrides); each episode writes its
own run folder. Results come back as the episode's ``metrics.json`` content plus ``run_dir``, or
``{"error": ...}`` for a failed episode (the sweep goes on). Episodes are independent and seeded,
so the numbers do not depend on the number of workers or their order.
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


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


def run_sweep(jobs: list[Job], workers: int = 2, label: str = "episode") -> list[dict[str, Any]]:
    """Run jobs with a process pool and a progress bar; results in job order."""
    from tqdm import tqdm

    results: list[dict[str, Any] | None] = [None] * len(jobs)
    with ProcessPoolExecutor(max_workers=max(1, workers)) as pool, tqdm(total=len(jobs), unit=label) as bar:
        futures = {pool.submit(run_job, j): i for i, j in enumerate(jobs)}
        for f in as_completed(futures):
            r = f.result()
            results[futures[f]] = r
            status = "FAILED" if "error" in r else f"iou3d {r['mean']['iou3d']:.3f}"
            bar.set_postfix_str(f"{r['strategy']} {r['scene']} {status}")
            bar.update(1)
    return [r for r in results if r is not None]


def scene_files() -> list[str]:
    """The benchmark scenes, relative to the repository root."""
    return [str(p.relative_to(REPO)) for p in sorted((REPO / "scenes").glob("scene*.toml"))]
