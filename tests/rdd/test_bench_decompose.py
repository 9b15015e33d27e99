"""The decomposition benchmark runs end to end at a tiny size and writes its table and figure."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_decompose.py"


def test_benchmark_tiny_run(tmp_path, benchmark_module):
    bench = benchmark_module("bench_decompose")
    out = tmp_path / "bench"
    res = bench.main(["--frames", "60", "--max-len", "20", "--entries", "300", "--embed-dim", "32",
                      "--backends", "exact,exact-dense,faiss-flat", "--repeat", "1", "--naive-limit", "10",
                      "--scaling", "40,60", "--scale", "400", "--scale-backends", "exact,faiss-flat,faiss-hnsw",
                      "--out", str(out)])
    b = res["backends"]
    # pruned exact, dense exact and faiss flat are all exact searches: the same optimum
    assert b["exact"]["objective"] == pytest.approx(b["exact-dense"]["objective"], abs=1e-4)
    assert b["exact"]["objective"] == pytest.approx(b["faiss-flat"]["objective"], abs=1e-3)
    assert res["naive_annoy_loop"]["extrapolated"] and res["naive_annoy_loop"]["queries"] > 0
    assert {r["T"] for r in res["scaling"]} == {40, 60}
    assert res["ood_vs_default"]["ratio"] > 0
    scale = {r["backend"]: r for r in res["scale"]}
    assert scale["faiss-flat"]["recall_at_1"] == pytest.approx(1.0)  # an exact search too
    assert 0 <= scale["faiss-hnsw"]["recall_at_1"] <= 1
    for name in ("results.json", "scaling.csv", "scaling.md", "scaling.png"):
        assert (out / name).is_file(), name
    assert json.loads((out / "results.json").read_text())["candidates"] == res["candidates"]


def test_rdd_core_benchmark_one_run(tmp_path, benchmark_module):
    """The one-run driver: decomposition per backend and size (approximate ones skipped above the
    limit), recall against exact, OOD vs default, and its summary table."""
    bench = benchmark_module("bench_rdd_core")
    out = tmp_path / "core"
    res = bench.main(["--frames", "50", "--max-len", "15", "--entries", "300", "--embed-dim", "32",
                      "--scale", "300,700", "--scale-embed-dim", "16", "--approx-max-entries", "300",
                      "--scale-backends", "exact,exact-dense,faiss-flat", "--naive-limit", "5", "--out", str(out)])
    rows = res["decompose"]["scale"]
    assert {(r["entries"], r["backend"]) for r in rows} == {
        (300, "exact"), (300, "exact-dense"), (300, "faiss-flat"), (700, "exact"), (700, "exact-dense")}
    assert all(r["frame_dim"] == 16 for r in rows)
    assert all(r["recall_at_1"] == pytest.approx(1.0) for r in rows)  # all three are exact searches
    summary = (out / "summary.md").read_text()
    assert "OOD" in summary and "| 700 | 16 | exact |" in summary


def test_rdd_core_benchmark_missing_data_is_one_line(tmp_path):
    """A --data folder that does not exist: exit 2 and one line naming the option and path, before any work."""
    missing = tmp_path / "no_such_episodes"
    proc = subprocess.run([sys.executable, str(BENCH.parent / "bench_rdd_core.py"), "--data", str(missing),
                           "--out", str(tmp_path / "core")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "--data" in proc.stderr and str(missing) in proc.stderr
    assert not (tmp_path / "core").exists()
