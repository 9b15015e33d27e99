"""One run of the harness: check the config, build the stages its mode needs, write ``results.json``.

The stages and their keys are ``graph.py`` (demos, labels, policy, database) and ``planner_stages.py``
(decompositions, planner base and finetune, oracle plans); the modes (closed loop, decompose only,
planner eval) are ``modes.py``; the summary blocks of the results are ``result_blocks.py``.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from experiments.cache.store import StageCache
from experiments.config.instantiate import check_call
from experiments.config.validate import validate_config
from experiments.report.result_blocks import main_metric, tracker_metrics
from experiments.report.results import RESULTS_FILE, RESULTS_FORMAT, method_label
from experiments.run import modes
from experiments.run.graph import Run, Unavailable, with_row_planner
from experiments.run.job import hardware, hydra_info, set_threads
from experiments.run.logs import quiet_libraries, show_progress, stage_lines
from rdd.atomic import write_json_atomic

log = logging.getLogger(__name__)


def preflight(run: Run) -> None:
    """Cheap checks before any long work: the runtime objects needed (keys and types: validate_config)."""
    if not run.decomposes():
        return
    takes: set[str] = set()
    for group in ("decomposer", "labeler"):
        component = run.component(group)
        # A parameter nothing fills fails now, not after the demos.
        check_call(component, component.runtime)
        takes |= set(component.runtime)
    if takes & {"encoder", "database"}:
        run.encoder()  # a missing checkpoint fails here, at once


def run(cfg: DictConfig) -> dict[str, Any]:
    """Run one configuration end to end; writes results.json and returns its summary."""
    validate_config(cfg)  # unknown or mistyped keys fail here, before anything is written
    cfg = with_row_planner(cfg)
    out_dir, choices, overrides, multirun, n_jobs = hydra_info()
    if out_dir is None:
        out_dir = Path(OmegaConf.select(cfg, "output_dir", default=None) or "outputs/run")
    out_dir.mkdir(parents=True, exist_ok=True)
    quiet_libraries()
    show_progress(not multirun or n_jobs == 1)  # parallel jobs' bars would interleave
    threads = set_threads(cfg, n_jobs)
    mode = str(OmegaConf.select(cfg, "mode")).split(".")[-1]
    resolved = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
    write_json_atomic(out_dir / "config_resolved.json", resolved)
    results: dict[str, Any] = {
        "format": RESULTS_FORMAT,
        "status": "ok",
        "mode": mode,
        "seed": int(cfg.seed),
        "choices": choices,
        "overrides": overrides,
        "label": method_label(overrides, choices),
        "hardware": {**hardware(), "torch_threads": threads, "parallel_jobs": n_jobs},
        "config": resolved,
    }
    from experiments.run.tracking import Tracker

    tracker = Tracker(cfg.wandb, resolved, out_dir,
                      name=f"{choices.get('experiment', 'run')}-{results['label']}-s{cfg.seed}")
    t_start = time.perf_counter()
    cache = StageCache.for_run(cfg.paths.cache_dir)
    try:
        if mode == "speed":
            from experiments.run.speed import measure_speed

            with cache.timed("speed"):
                results["speed"] = measure_speed(cfg)
        else:
            run_obj = Run(cfg, out_dir, cache)
            try:
                preflight(run_obj)
            except Unavailable as exc:
                if not cfg.skip_unavailable:
                    raise
                results.update(status="skipped", reason=str(exc))
                log.warning("skipped: %s", exc)
            if results["status"] == "ok":
                if mode == "decompose":
                    modes.decompose_only(run_obj, results)
                elif mode == "planner_eval":
                    modes.planner_eval(run_obj, results)
                else:
                    modes.hierarchical(run_obj, results)
    except BaseException as exc:
        results.update(status="failed", reason=f"{type(exc).__name__}: {exc}")
        raise
    finally:
        results["timings"] = {k: {"seconds": round(v.seconds, 3), "cached": v.cached}
                              for k, v in cache.timings.items()}
        results["wall_seconds"] = round(time.perf_counter() - t_start, 3)
        for line in stage_lines(cache.timings):
            log.info(line)
        try:
            write_json_atomic(out_dir / RESULTS_FILE, results)
            tracker.log(tracker_metrics(results))
            tracker.finish()
        finally:
            cache.close()
    summary = {
        "output_dir": str(out_dir),
        "status": results["status"],
        "main_metric": main_metric(results),
    }
    if cfg.print_table and results["status"] == "ok":
        from experiments.tables import write_tables

        md, written = write_tables(out_dir, out_dir / "tables")  # this run's table, LaTeX and plot
        print(md)
        print(f"results: {out_dir / RESULTS_FILE}")
        for path in written:
            if path.suffix == ".png":
                print(f"plot: {path}")
    return summary

