"""``python -m rdd`` end to end on native episodes with known sub-task boundaries."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rdd.cli import main
from rdd.cli.common import parse_options
from rdd.data.native import save_episode
from rdd.testing.native_synth import colour_episode

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("native")
    for k, lengths in enumerate([(12, 15, 13), (14, 12, 15), (13, 14, 12), (15, 13, 14)]):
        save_episode(colour_episode(f"ep{k}", lengths, k), root / f"ep{k}")
    return root


def run(*argv: str) -> int:
    return main([str(a) for a in argv])


def test_parse_options():
    assert parse_options(["a=1", "b=[1,2]", "c=observation.state", "d-e=true"], "--x") == {
        "a": 1, "b": [1, 2], "c": "observation.state", "d_e": True}


def test_full_pipeline(data, tmp_path, capsys):
    cache = ["--cache-dir", tmp_path / "cache"]
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "expert",
               "--out", tmp_path / "expert.json") == 0
    expert = json.loads((tmp_path / "expert.json").read_text())
    # The gripper state first differs at frames 12 and 27 (the arm never rests), then the last frame.
    assert expert["episodes"][0]["keyframes"] == [12, 27, 39]
    assert run("build-db", "--format", "native", "--data", data, "--exclude", "ep0", "--encoder",
               "pixels", "--encoder-option", "size=4", *cache, "--out", tmp_path / "db") == 0
    assert run("decompose", "--format", "native", "--data", data, "--include", "ep0",
               "--decomposer", "rdd", "--db", tmp_path / "db", "--encoder-option", "size=4",
               "--max-len", "30", *cache, "--out", tmp_path / "rdd.json") == 0
    out = json.loads((tmp_path / "rdd.json").read_text())
    rec = out["episodes"][0]
    assert out["config"]["decomposer"] == "rdd" and out["config"]["encoder"] == "pixels"
    assert rec["episode"] == "ep0" and rec["num_frames"] == 40
    assert rec["segments"][0][0] == 0 and rec["segments"][-1][1] == 40
    assert len(rec["scores"]) == len(rec["segments"]) == len(rec["instructions"])
    assert rec["keyframes"] == [e - 1 for _, e in rec["segments"]]
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "uvd",
               "--encoder", "pixels", "--encoder-option", "size=4", "--option", "min_interval=5",
               *cache, "--out", tmp_path / "uvd.json") == 0
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "uniform",
               "--option", "n_segments=3", "--out", tmp_path / "uniform.json") == 0
    capsys.readouterr()
    assert run("evaluate", "--pred", tmp_path / "uniform.json", "--gt", tmp_path / "expert.json",
               "--tolerance", "3", "--out", tmp_path / "eval.json") == 0
    assert "MEAN" in capsys.readouterr().out
    ev = json.loads((tmp_path / "eval.json").read_text())
    # Uniform thirds [0,14),[14,27),[27,40) vs expert [0,13),[13,28),[28,40).
    assert ev["methods"]["uniform"]["episodes"]["ep0"]["miou"] == pytest.approx((13 / 14 + 13 / 15 + 12 / 13) / 3)
    assert run("plot", "--pred", tmp_path / "rdd.json", tmp_path / "uvd.json", "--gt",
               tmp_path / "expert.json", "--format", "native", "--data", data, "--episode", "ep0",
               "--out", tmp_path / "fig.png") == 0
    assert (tmp_path / "fig.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_errors_name_the_option(data, tmp_path, capsys):
    assert run("decompose", "--format", "native", "--data", tmp_path / "nope", "--decomposer",
               "uniform", "--out", tmp_path / "x.json") == 2
    assert "--data" in capsys.readouterr().err
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "rdd",
               "--out", tmp_path / "x.json") == 2
    assert "--db" in capsys.readouterr().err
    assert run("decompose", "--format", "native", "--data", data, "--include", "zzz",
               "--decomposer", "uniform", "--out", tmp_path / "x.json") == 2
    assert "--include" in capsys.readouterr().err
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "uniform",
               "--option", "bogus=1", "--out", tmp_path / "x.json") == 2
    assert "--option" in capsys.readouterr().err
    assert run("evaluate", "--pred", tmp_path / "missing.json", "--gt", tmp_path / "m.json") == 2
    assert "missing.json" in capsys.readouterr().err


def test_module_entry_point():
    res = subprocess.run([sys.executable, "-m", "rdd", "--help"], cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0
    for cmd in ("build-db", "decompose", "evaluate", "plot", "demo"):
        assert cmd in res.stdout
    assert res.stdout.startswith("usage: python -m rdd ")


def test_console_script_usage_names_rdd():
    """The ``rdd`` script pip generates calls ``rdd.cli.main()``: its usage lines say ``rdd``."""
    script = "import sys; from rdd.cli import main; sys.exit(main())"
    res = subprocess.run([sys.executable, "-c", script, "decompose"], cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 2
    assert res.stderr.startswith("usage: rdd decompose ") and "python -m" not in res.stderr


def test_evaluate_help_names_every_column(capsys):
    """``evaluate --help`` says what each printed column is and shows --tolerance's default."""
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    text = capsys.readouterr().out
    assert "(default 2)" in text
    for column, meaning in (("mIoU", "PREDICTED segments"), ("sym-mIoU", "missed ground-truth"),
                            ("bP bR bF1", "--tolerance")):
        line = next(i for i, s in enumerate(text.splitlines()) if s.strip().startswith(column))
        assert meaning in " ".join(text.splitlines()[line:line + 3]), column


def test_demo_subcommand(tmp_path, capsys):
    assert run("demo", "--json", tmp_path / "demo.json") == 0
    assert (tmp_path / "demo.json").is_file()
    assert "novelty" in capsys.readouterr().out


def test_bad_inputs_are_one_line_errors(data, tmp_path, capsys, monkeypatch):
    """Each bad input of issue 14: exit 2, one line on stderr naming the option or file, nothing written."""
    base = ["decompose", "--format", "native", "--data", data]

    def fails(*argv, expect: str) -> None:
        capsys.readouterr()
        assert run(*argv) == 2, argv
        err = capsys.readouterr().err
        assert expect in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err

    fails(*base, "--decomposer", "expert", "--stopping-delta", "-1", "--out", tmp_path / "x.json",
          expect="stopping_delta must be >= 0")
    fails(*base, "--decomposer", "uniform", "--option", "n_segments=2.5", "--out", tmp_path / "x.json",
          expect="n_segments must be a whole number")
    fails(*base, "--decomposer", "uniform", "--option", "n_segments=0", "--out", tmp_path / "x.json",
          expect="n_segments must be >= 1")
    fails(*base, "--decomposer", "expert", "--option", "stoping_delta=0.2", "--out", tmp_path / "x.json",
          expect="unknown option(s) ['stoping_delta']")
    fails(*base, "--decomposer", "uvd", "--encoder", "pixels", "--option", "gamma=-1", "--no-cache",
          "--out", tmp_path / "x.json", expect="gamma must be > 0.0")
    fails(*base, "--decomposer", "uvd", "--encoder", "pixels", "--option", "min_interval=[3]", "--no-cache",
          "--out", tmp_path / "x.json", expect="min_interval must be a whole number")
    fails(*base, "--decomposer", "rdd", "--db", tmp_path / "nodb", "--option", "alpha_x=1",
          "--out", tmp_path / "x.json", expect="unknown option(s) ['alpha_x']")
    fails(*base, "--decomposer", "uniform", "--reader-option", "episodes=[1]", "--out", tmp_path / "x.json",
          expect="--reader-option")
    assert not (tmp_path / "x.json").exists()
    (tmp_path / "adir").mkdir()
    fails(*base, "--decomposer", "uniform", "--out", tmp_path / "adir", expect="is an existing folder")
    (tmp_path / "afile").write_text("keep me")
    fails("build-db", "--format", "native", "--data", data, "--encoder", "pixels", "--out", tmp_path / "afile",
          expect="is an existing file")
    assert (tmp_path / "afile").read_text() == "keep me"
    fails(*base, "--decomposer", "uniform", "--out", tmp_path / "afile", expect="--force")
    assert (tmp_path / "afile").read_text() == "keep me"
    fails("plot", "--pred", tmp_path / "afile", "--format", "native", "--data", data, "--out", tmp_path / "f.gif",
          expect="unsupported figure format '.gif'")

    # -v shows the traceback of the same error.
    capsys.readouterr()
    assert run("-v", *base, "--decomposer", "uniform", "--option", "n_segments=2.5", "--out", tmp_path / "x.json") == 2
    assert "Traceback" in capsys.readouterr().err

    # Ctrl-C: status 130, one line, no output file.
    from rdd.decomposers import uniform

    def interrupted(self, episode):
        raise KeyboardInterrupt

    monkeypatch.setattr(uniform.UniformDecomposer, "decompose", interrupted)
    capsys.readouterr()
    assert run(*base, "--decomposer", "uniform", "--out", tmp_path / "ctrl_c.json") == 130
    assert "interrupted" in capsys.readouterr().err and not (tmp_path / "ctrl_c.json").exists()


def test_truncated_and_refused_pickles(tmp_path, capsys):
    import pickle

    ep = tmp_path / "ep"
    ep.mkdir()
    (ep / "low_dim_obs.pkl").write_bytes(pickle.dumps([{"a": np.ones(3)}])[:-5])
    capsys.readouterr()
    assert run("decompose", "--format", "rlbench", "--data", ep, "--decomposer", "uniform",
               "--out", tmp_path / "x.json") == 2
    err = capsys.readouterr().err
    assert "low_dim_obs.pkl" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    (ep / "low_dim_obs.pkl").write_bytes(b"cos\nsystem\n(S'true'\ntR.")
    assert run("decompose", "--format", "rlbench", "--data", ep, "--decomposer", "uniform",
               "--out", tmp_path / "x.json") == 2
    err = capsys.readouterr().err
    assert "refusing to load global os.system" in err and "low_dim_obs.pkl" in err and "Traceback" not in err


def test_evaluate_validates_and_compares_methods(tmp_path, capsys):
    def write(name, episodes):
        path = tmp_path / name
        path.write_text(json.dumps({"config": {"decomposer": name.split(".")[0]}, "episodes": [
            {"episode": ep, "num_frames": n, "segments": segs} for ep, n, segs in episodes]}))
        return path

    gt = write("gt.json", [("a", 10, [[0, 5], [5, 10]]), ("b", 8, [[0, 8]])])
    good = write("good.json", [("a", 10, [[0, 5], [5, 10]]), ("b", 8, [[0, 4], [4, 8]])])
    half = write("half.json", [("a", 10, [[0, 10]])])
    overlap = write("overlap.json", [("a", 10, [[0, 6], [5, 10]]), ("b", 8, [[0, 8]])])
    outside = write("outside.json", [("a", 10, [[0, 5], [5, 12]]), ("b", 8, [[0, 8]])])
    for bad, expect in ((overlap, "not a partition"), (outside, "must end at 10")):
        capsys.readouterr()
        assert run("evaluate", "--pred", bad, "--gt", gt) == 2
        err = capsys.readouterr().err
        assert expect in err and "'a'" in err
    capsys.readouterr()
    assert run("evaluate", "--pred", half, "--gt", gt) == 2
    err = capsys.readouterr().err
    assert "cover different episodes" in err and "--allow-partial" in err
    assert run("evaluate", "--pred", f"g={good}", f"h={half}", "--gt", gt, "--allow-partial",
               "--out", tmp_path / "ev.json") == 0
    table = capsys.readouterr().out
    assert "g " in table and "h " in table
    ev = json.loads((tmp_path / "ev.json").read_text())
    # Independent values: g is exact on 'a' (1.0) and halves 'b' (IoU 0.5 each) -> mean 0.75;
    # h predicts one segment on 'a' (IoU 0.5 with either half) and leaves 'b' out.
    assert ev["methods"]["g"]["mean"]["miou"] == pytest.approx(0.75)
    assert ev["methods"]["h"]["mean"]["miou"] == pytest.approx(0.5)
    assert ev["methods"]["h"]["left_out"] == {"pred_only": [], "gt_only": ["b"]}
    # Two unlabelled files of the same decomposer are ambiguous; the same label merges folds.
    dup = write("good2.json", [("c", 4, [[0, 4]])])
    (tmp_path / "good2.json").write_text((tmp_path / "good2.json").read_text().replace('"good2"', '"good"'))
    assert run("evaluate", "--pred", good, dup, "--gt", gt, "--allow-partial") == 2
    assert "already labelled 'good'" in capsys.readouterr().err


@pytest.mark.parametrize("suffix,magic", [(".png", b"\x89PNG"), (".pdf", b"%PDF"), (".svg", b"<?xml")])
def test_plot_format_follows_the_file_name(data, tmp_path, suffix, magic):
    pred = tmp_path / "u.json"
    assert run("decompose", "--format", "native", "--data", data, "--include", "ep0", "--decomposer", "uniform",
               "--option", "n_segments=3", "--out", pred) == 0
    out = tmp_path / f"fig{suffix}"
    assert run("plot", "--pred", pred, "--format", "native", "--data", data, "--out", out) == 0
    assert out.read_bytes()[:len(magic)] == magic


def test_outputs_respect_the_umask(data, tmp_path):
    old = os.umask(0o027)
    try:
        assert run("decompose", "--format", "native", "--data", data, "--decomposer", "uniform",
                   "--option", "n_segments=3", "--out", tmp_path / "u.json") == 0
    finally:
        os.umask(old)
    assert (tmp_path / "u.json").stat().st_mode & 0o777 == 0o640


def test_build_db_calibrates_and_decompose_uses_it(data, tmp_path, capsys):
    cache = ["--cache-dir", tmp_path / "cache", "--encoder-option", "size=4"]
    assert run("build-db", "--format", "native", "--data", data, "--exclude", "ep0", "--encoder",
               "pixels", *cache, "--out", tmp_path / "db") == 0
    assert "calibrated on 3 held-out episodes" in capsys.readouterr().out
    manifest = json.loads((tmp_path / "db" / "manifest.json").read_text())
    cal = manifest["calibration"]
    assert cal["episodes"] == ["ep1", "ep2", "ep3"] and manifest["frames_episodes"] == ["ep1", "ep2", "ep3"]
    assert cal["score"] == max(r["miou"] for r in cal["results"])
    # entries of unannotated episodes carry no instruction (the goal is no sub-task): decompose gives none
    assert run("decompose", "--format", "native", "--data", data, "--include", "ep0",
               "--decomposer", "rdd", "--db", tmp_path / "db", *cache, "--out", tmp_path / "a.json") == 0
    out = json.loads((tmp_path / "a.json").read_text())
    assert out["config"]["alpha"] == cal["chosen"]["alpha"]
    assert out["config"]["option_source"]["alpha"] == "calibration"
    assert set(out["episodes"][0]["instructions"]) == {""}
    # the index by its name and by its older one (scripts pass --option backend=...): the same run
    for key in ("index", "backend"):
        assert run("decompose", "--format", "native", "--data", data, "--include", "ep0", "--decomposer", "rdd",
                   "--db", tmp_path / "db", "--option", f"{key}=annoy", *cache, "--out", tmp_path / f"{key}.json") == 0
    by_index, by_backend = (json.loads((tmp_path / f"{k}.json").read_text()) for k in ("index", "backend"))
    assert by_index["config"]["backend"] == by_backend["config"]["backend"] == "annoy"
    assert by_index["config"]["options"] == {"index": "annoy"} and by_backend["config"]["options"] == {"backend": "annoy"}
    assert by_index["episodes"] == by_backend["episodes"]
    assert run("decompose", "--format", "native", "--data", data, "--include", "ep0", "--alpha", "7",
               "--decomposer", "rdd", "--db", tmp_path / "db", *cache, "--out", tmp_path / "b.json") == 0
    cfg = json.loads((tmp_path / "b.json").read_text())["config"]
    assert cfg["alpha"] == 7 and cfg["option_source"]["alpha"] == "given"
    assert cfg["min_len"] == cal["chosen"]["min_len"]
    # rerun with another grid: the manifest records it
    assert run("calibrate", "--db", tmp_path / "db", "--alpha", "0.5,3", "--min-len", "2",
               "--max-len", "none", "--backend", "exact") == 0  # --backend: --index by its older name
    cal2 = json.loads((tmp_path / "db" / "manifest.json").read_text())["calibration"]
    assert cal2["grid"] == {"alpha": [0.5, 3.0], "min_len": [2], "max_len": [None]}
    assert cal2["chosen"]["alpha"] in (0.5, 3.0, 1.0)
    capsys.readouterr()
    assert run("calibrate", "--db", tmp_path / "db", "--alpha", ",") == 2
    err = capsys.readouterr().err
    assert "--alpha" in err and "empty" in err
    assert json.loads((tmp_path / "db" / "manifest.json").read_text())["calibration"] == cal2


def test_build_db_no_calibrate_and_one_episode(data, tmp_path, capsys):
    common = ["--format", "native", "--data", data, "--encoder", "pixels", "--encoder-option", "size=4",
              "--no-cache"]
    assert run("build-db", *common, "--no-calibrate", "--out", tmp_path / "db") == 0
    manifest = json.loads((tmp_path / "db" / "manifest.json").read_text())
    assert manifest["calibration"] is None and manifest["frames_episodes"] == []
    assert not (tmp_path / "db" / "frames.npz").exists()
    capsys.readouterr()
    assert run("calibrate", "--db", tmp_path / "db") == 2
    err = capsys.readouterr().err
    assert "--db" in err and "--no-calibrate" in err
    assert json.loads((tmp_path / "db" / "manifest.json").read_text()) == manifest
    assert run("build-db", *common, "--include", "ep1", "--out", tmp_path / "one") == 0
    assert "calibration skipped" in capsys.readouterr().err
    assert json.loads((tmp_path / "one" / "manifest.json").read_text())["calibration"] is None
