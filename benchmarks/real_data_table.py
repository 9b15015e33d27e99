"""The real-data table (issue 44.4; the paper's Table 5 for the data we have), in one resumable command.

1. RLBench open_drawer, leave one episode out: for each episode, ``build-db`` from the others
   (segmented by the keyframe rule) and ``decompose`` it with rdd and rdd_ood (``--option mode=ood``);
   uvd, uniform (n_segments = the median segment count of the fold's training annotation, i.e. of its
   database) and the rule (``--decomposer expert``) on every episode; all scored against the rule.
2. G1 (two LeRobot datasets): a database from the ``--train`` episodes per annotation, (a) the
   project's hand rule (``--decomposer expert``) and (b) the hysteresis annotation of
   ``benchmarks/annotate_hand_hysteresis.py`` (its annotated copies, ``build-db --segments subtasks``);
   the ``--test`` episodes decomposed by rdd and rdd_ood with each database, by uvd, uniform and the
   rule; every method scored against each annotation.

Scores come from ``python -m rdd evaluate --tolerance T`` (``evaluate --help``): mIoU (the paper's),
symmetric mIoU, boundary F1 within T frames. Every step is a ``python -m rdd`` (or annotation script)
subprocess whose output under ``--out`` is reused on a rerun while its command and inputs are the
same (``real_data_steps``), so a killed run resumes; ``--out/log.txt`` holds the details, the
terminal one line per step. Writes ``--out/table.md`` and ``--out/results.json``. Example:

    python benchmarks/real_data_table.py --out outputs/real_table \\
        --rlbench $RDD_TEST_DATA/rlbench/open_drawer/all_variations/episodes \\
        --g1 $RDD_TEST_DATA/lerobot/unitree_g1_pick_bottle --g1 $RDD_TEST_DATA/lerobot/unitree_g1_pick_bottle_30
"""

from __future__ import annotations

import argparse
import re
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from real_data_steps import (  # noqa: E402  (the sibling module, found from this file's folder)
    StepError,
    Steps,
    index_list,
    means,
    median_count,
    read_records,
    segment_counts,
    write_records,
)

from rdd.atomic import write_json_atomic, write_text_atomic  # noqa: E402
from rdd.cli.components import DEFAULT_ENCODER  # noqa: E402
from rdd.data.lerobot.reader import episode_name, episode_names  # noqa: E402
from rdd.errors import InputError  # noqa: E402

OOD = ["--option", "mode=ood"]  # the RDD decomposer's OOD mode (paper Eq. 3.5)
METRICS = (("miou", "mIoU"), ("symmetric_miou", "sym mIoU"), ("boundary_f1", "F1"))


def rlbench_names(root: Path, wanted: Sequence[str] | None) -> list[str]:
    """The episodes to use: ``wanted``, else every ``episodeN`` folder of ``root`` in N order."""
    if not root.is_dir():
        raise InputError(f"--rlbench {root}: not a folder of RLBench episodes")
    found = sorted((p.name for p in root.iterdir() if re.fullmatch(r"episode\d+", p.name) and p.is_dir()),
                   key=lambda n: int(n[7:]))
    names = list(wanted) if wanted else found
    missing = sorted(set(names) - set(found))
    if missing or len(names) < 2:
        raise InputError(f"--rlbench-episodes: {missing or names} ({'not in ' + str(root) if missing else 'need 2'})")
    return names


def run_rlbench(args: argparse.Namespace, steps: Steps, folder: Path) -> dict[str, Any]:
    """Leave-one-out folds on RLBench, scored against the keyframe rule."""
    sec, root = "rlbench", Path(args.rlbench).resolve()
    names = rlbench_names(root, args.rlbench_episodes)
    data = ["--format", "rlbench", "--data", root]

    def decompose(label: str, out: Path, include: Sequence[str], *extra: Any, deps: Sequence[Path] = ()) -> Path:
        return steps.cli(sec, label, out, ["decompose", *data, "--include", *include, *extra, "--out", out], deps)

    rule = decompose("rule", folder / "rule.json", names, "--decomposer", "expert")
    preds = [("rule", rule)]
    preds += [(label, decompose(step, folder / f"{label}.json", names, "--decomposer", "uvd", *encoder_args(args), *extra))
              for label, step, _, extra in uvd_runs(args)]
    n_of: dict[str, int] = {}
    for name in names:
        db = folder / f"db_{name}"
        steps.cli(sec, f"build-db without {name}", db, ["build-db", *data, "--include", *[n for n in names if n != name],
                                                        *encoder_args(args), *shlex.split(args.build_opt), "--out", db])
        n_of[name] = median_count(segment_counts(db))
        for method, extra in (("rdd", []), ("rdd_ood", OOD)):
            preds.append((method, decompose(f"{method} {name}", folder / f"{method}_{name}.json", [name],
                                            "--decomposer", "rdd", "--db", db, *encoder_args(args, False), *extra,
                                            *shlex.split(args.decompose_opt), deps=[db])))
    for n in sorted(set(n_of.values())):
        eps = [e for e in names if n_of[e] == n]
        preds.append(("uniform", decompose(f"uniform n={n}", folder / f"uniform_n{n}.json", eps, "--decomposer",
                                           "uniform", "--option", f"n_segments={n}")))
    scores = {"rule": evaluate(args, steps, sec, folder / "eval_rule.json", preds, rule)}
    counts = {n: sum(v == n for v in n_of.values()) for n in sorted(set(n_of.values()))}
    ns = f"{n_of[names[0]]} in every fold" if len(counts) == 1 else ", ".join(f"{n} in {k} folds" for n, k in counts.items())
    rows = [("rdd", "rdd"), ("rdd_ood", "rdd_ood"), *[(label, name) for label, _, name, _ in uvd_runs(args)],
            ("uniform", f"uniform (n = {ns})"), ("rule", "rule (the ground truth itself)")]
    return {"title": f"RLBench open_drawer, leave one episode out ({len(names)} folds)",
            "about": (f"Each fold's database: the other {len(names) - 1} episodes of `{root}`, segmented by the "
                      f"keyframe rule (`build-db`, calibrated). Ground truth: the RLBench keyframe rule "
                      f"(`decompose --decomposer expert`). uniform: n_segments = the median segment count of "
                      f"the fold's database: {ns}."),
            "episodes": names, "uniform_n": n_of, "annotations": ["rule"], "rows": table_rows(rows, scores),
            "commands": steps.commands.get(sec, [])}


def holders(held: dict[int, Path], wanted: Sequence[int], option: str) -> dict[int, Path]:
    """Episode index -> the ``--g1`` dataset holding its files, for each of ``wanted``."""
    missing = [i for i in wanted if i not in held]
    if missing:
        raise InputError(f"{option}: episodes {missing} have no files in any --g1 dataset")
    return {i: held[i] for i in wanted}


def run_g1(args: argparse.Namespace, steps: Steps, folder: Path) -> dict[str, Any]:
    """G1: databases from the training episodes per annotation, every method scored against each."""
    sec = "g1"
    roots = [Path(r).resolve() for r in args.g1]
    if len({r.name for r in roots}) != len(roots):
        raise InputError("--g1: two datasets share a folder name")
    train, test = index_list(args.train, "--train"), index_list(args.test, "--test")
    if set(train) & set(test):
        raise InputError(f"--train and --test share episodes {sorted(set(train) & set(test))}")
    held: dict[int, Path] = {}  # episode index -> the first --g1 dataset holding its files
    for root in roots:
        for name in episode_names(root, skip_missing=True):
            held.setdefault(int(name.rsplit("_", 1)[1]), root)
    train_root = set(holders(held, train, "--train").values())
    if len(train_root) != 1:
        raise InputError(f"--train: episodes from {len(train_root)} datasets (build-db reads one --data)")
    (train_root,) = train_root
    groups: dict[Path, list[str]] = {}
    for i, root in holders(held, test, "--test").items():
        groups.setdefault(root, []).append(episode_name(i))

    def data(root: Path) -> list[Any]:
        return ["--format", "lerobot", "--data", root, "--reader-option", "skip_missing=true"]

    def decompose(label: str, stem: str, *extra: Any, deps: Sequence[Path] = ()) -> list[Path]:
        """One decompose per dataset holding test episodes."""
        return [steps.cli(sec, f"{label} ({root.name})", folder / f"{stem}_{root.name}.json",
                          ["decompose", *data(root), "--include", *names, *extra, "--out",
                           folder / f"{stem}_{root.name}.json"], deps) for root, names in groups.items()]

    hands, copies = folder / "hysteresis.json", folder / "hysteresis_copies"
    steps.script(sec, "hysteresis annotation", hands, "annotate_hand_hysteresis.py",
                 [*[a for r in roots for a in ("--data", r)], "--copies", copies, "--json", hands], clear=[copies])
    rule = decompose("rule", "rule", "--decomposer", "expert")
    names = {n for ns in groups.values() for n in ns}
    gts = {"rule": folder / "gt_rule.json", "hysteresis": folder / "gt_hysteresis.json"}
    steps.step(sec, "ground truth: rule", gts["rule"], ["#", gts["rule"].name, "= the episodes of", *[f.name for f in rule]], deps=rule, action=lambda: write_records(
        gts["rule"], [r for f in rule for r in read_records(f)], {"annotation": "rule", "merged": [str(f) for f in rule]}))
    steps.step(sec, "ground truth: hysteresis", gts["hysteresis"], ["#", gts["hysteresis"].name, "= the episodes", *sorted(names), "of", hands.name], deps=[hands],
               action=lambda: write_records(gts["hysteresis"], [r for r in read_records(hands) if r["episode"] in names],
                                            {"annotation": "hysteresis", "from": str(hands)}))
    preds = [("rule", f) for f in rule]
    for label, step, _, extra in uvd_runs(args):
        preds += [(label, f) for f in decompose(step, label, "--decomposer", "uvd", *encoder_args(args), *extra)]
    n_of: dict[str, int] = {}
    for ann, source, segments in (("rule", train_root, "expert"), ("hysteresis", copies / train_root.name, "subtasks")):
        db = folder / f"db_{ann}"
        steps.cli(sec, f"build-db ({ann})", db, ["build-db", *data(source), "--include", *map(episode_name, train),
                                                 "--segments", segments, *encoder_args(args),
                                                 *shlex.split(args.build_opt), "--out", db],
                  deps=[hands] if ann == "hysteresis" else [])
        n_of[ann] = median_count(segment_counts(db))
        for method, extra in (("rdd", []), ("rdd_ood", OOD)):
            preds += [(f"{method}@{ann}", f) for f in decompose(
                f"{method} (db: {ann})", f"{method}-{ann}", "--decomposer", "rdd", "--db", db,
                *encoder_args(args, False), *extra, *shlex.split(args.decompose_opt), deps=[db])]
    for n in sorted(set(n_of.values())):
        preds += [(f"uniform_n{n}", f) for f in decompose(f"uniform n={n}", f"uniform_n{n}", "--decomposer",
                                                           "uniform", "--option", f"n_segments={n}")]
    scores = {ann: evaluate(args, steps, sec, folder / f"eval_{ann}.json", preds, gt) for ann, gt in gts.items()}
    rows = [(f"{m}@{a}", f"{m} (db: {a})") for m in ("rdd", "rdd_ood") for a in gts]
    rows += [(label, name) for label, _, name, _ in uvd_runs(args)]
    rows += [(f"uniform_n{n}", f"uniform (n = {n}: median of the training {' and '.join(a for a in n_of if n_of[a] == n)} "
                               "annotation)") for n in sorted(set(n_of.values()))]
    rows += [("rule", "rule (`--decomposer expert`)")]
    return {"title": f"G1, {len(train)} -> {len(test)} episodes",
            "about": (f"Databases: episodes {args.train} of `{train_root}`, segmented by each annotation (`build-db`, "
                      f"calibrated); decomposed: episodes {args.test}. Annotations: the rule (`decompose --decomposer "
                      "expert`) and the hand hysteresis (`benchmarks/annotate_hand_hysteresis.py`). uniform: "
                      "n_segments = the median segment count of a training annotation."),
            "train": list(map(episode_name, train)), "test": sorted(names), "uniform_n": n_of,
            "annotations": list(gts), "rows": table_rows(rows, scores), "commands": steps.commands.get(sec, [])}


def uvd_runs(args: argparse.Namespace) -> list[tuple[str, str, str, list[str]]]:
    """uvd on the default views, then on each ``--uvd-views``: (label and output stem, step name, row
    name, extra decompose arguments)."""
    return [("uvd", "uvd", "uvd", []), *[(f"uvd_{v}", f"uvd views {v}", f"uvd (`--views {v}`)", ["--views", *v.split()])
                                          for v in args.uvd_views or []]]


def encoder_args(args: argparse.Namespace, name: bool = True) -> list[str]:
    """``--encoder`` (unless rdd, which takes its database's) and each ``--encoder-option``."""
    return [*(["--encoder", args.encoder] if name else []),
            *[a for opt in args.encoder_option or [] for a in ("--encoder-option", opt)]]


def evaluate(args: argparse.Namespace, steps: Steps, sec: str, out: Path, preds: Sequence[tuple[str, Path]],
             gt: Path) -> dict[str, dict[str, float]]:
    """One ``evaluate`` of every prediction against ``gt``: label -> mean metrics."""
    steps.cli(sec, f"evaluate against {gt.stem}", out,
              ["evaluate", "--pred", *[f"{label}={f}" for label, f in preds], "--gt", gt,
               "--tolerance", args.tolerance, "--out", out], deps=[*dict.fromkeys([f for _, f in preds]), gt])
    return means(out)


def table_rows(rows: Sequence[tuple[str, str]], scores: dict[str, dict[str, dict[str, float]]]) -> list[dict]:
    """The rows of a table: method label, shown name, and its scores against each annotation; the rule
    scored against itself is marked trivial."""
    return [{"method": label, "name": name,
             "scores": {ann: {**s[label], "trivial": label == "rule" and ann == "rule"} for ann, s in scores.items()}}
            for label, name in rows]


def markdown(results: dict[str, Any]) -> str:
    """``table.md``: one table per dataset (rows methods, columns per annotation) and its commands."""
    tol = results["settings"]["tolerance"]
    lines = ["# Real-data table", "", f"Made by `{results['command']}` ({results['finished']}); encoder "
             f"`{results['settings']['encoder']}`. Means over the decomposed episodes of `python -m rdd evaluate "
             f"--tolerance {tol}`: mIoU = the RDD paper's (over the predicted segments), sym mIoU = symmetric, "
             f"F1 = boundary F1 with cuts matched within +-{tol} frames (`evaluate --help`). The leave-one-out "
             "command of docs/cli.md evaluates at its default --tolerance 2 (its figures are mIoU, which the "
             f"tolerance does not change); this table's F1 is at +-{tol}."]
    for part in results["datasets"].values():
        anns = part["annotations"]
        head = [f"{a}: {m}" if len(anns) > 1 else m for a in anns for _, m in METRICS]
        head = [h + f" +-{tol}" if h.endswith("F1") else h for h in head]
        lines += ["", f"## {part['title']}", "", part["about"], "", "| method | " + " | ".join(head) + " |",
                  "|---" * (len(head) + 1) + "|"]
        for row in part["rows"]:
            cells = [f"{row['scores'][a][k]:.3f}" + (" (trivial)" if row["scores"][a]["trivial"] else "")
                     for a in anns for k, _ in METRICS]
            lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
        lines += ["", "Commands (from the checkout's root):", "```", *part["commands"], "```"]
    return "\n".join(lines) + "\n"


def parse(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command's options."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="folder of every step's output, table.md, results.json, log.txt")
    p.add_argument("--rlbench", metavar="DIR", help="RLBench open_drawer episodes (episode0, episode1, ...)")
    p.add_argument("--rlbench-episodes", nargs="+", metavar="NAME", help="only these (default: every episodeN)")
    p.add_argument("--g1", action="append", metavar="DIR", help="a G1 LeRobot dataset (repeat for several)")
    p.add_argument("--train", default="16-35", help="G1 database episodes (default 16-35)")
    p.add_argument("--test", default="36-45,1,2", help="G1 decomposed episodes (default 36-45,1,2)")
    p.add_argument("--only", choices=("rlbench", "g1"), help="make one table (default both)")
    p.add_argument("--encoder", default=DEFAULT_ENCODER, help=f"encoder of rdd and uvd (default {DEFAULT_ENCODER})")
    p.add_argument("--encoder-option", action="append", metavar="KEY=VALUE", help="passed to every encoding step")
    p.add_argument("--build-opt", default="", metavar="ARGS", help="appended to each build-db, e.g. --build-opt=--no-calibrate")
    p.add_argument("--decompose-opt", default="", metavar="ARGS",
                   help="appended to each rdd and rdd_ood decompose, e.g. '--alpha 0.5'")
    p.add_argument("--uvd-views", action="append", metavar="VIEWS",
                   help="one more uvd row decomposing these views, e.g. --uvd-views state (repeat for more)")
    p.add_argument("--tolerance", type=int, default=5, help="boundary F1 tolerance in frames (default 5)")
    p.add_argument("--force", action="store_true", help="remake a finished table (its steps are still reused)")
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Make (or resume) the tables; return what ``results.json`` holds."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse(argv)
    out = Path(args.out).resolve()
    parts = [p for p in ("rlbench", "g1") if args.only in (None, p)]
    for part in parts:
        if not getattr(args, part):
            raise InputError(f"--{part} DIR is needed for the {part} table (or --only {'g1' if part == 'rlbench' else 'rlbench'})")
    if (out / "table.md").exists() and not args.force:
        raise InputError(f"--out {out}: table.md is finished; pass --force to remake it (finished steps are reused)")
    steps = Steps(out, out / "log.txt", echo=lambda line: print(line, flush=True))
    command = shlex.join(["python", "benchmarks/real_data_table.py", *argv])
    steps.log(f"== {time.strftime('%Y-%m-%d %H:%M:%S')} {command}")
    runners = {"rlbench": run_rlbench, "g1": run_g1}
    datasets = {part: runners[part](args, steps, out / part) for part in parts}
    results = {"command": command, "finished": time.strftime("%Y-%m-%d %H:%M:%S"),
               "settings": {"encoder": args.encoder, "encoder_options": args.encoder_option or [],
                            "build_opt": args.build_opt, "decompose_opt": args.decompose_opt,
                            "tolerance": args.tolerance}, "datasets": datasets}
    write_json_atomic(out / "results.json", results)
    write_text_atomic(out / "table.md", markdown(results))
    steps.log(f"wrote {out / 'table.md'} and results.json")
    print(f"wrote {out / 'table.md'} and {out / 'results.json'} ({steps.count} steps)")
    return results


if __name__ == "__main__":
    try:
        main()
    except (InputError, StepError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
