"""Can a frozen EfficientNet-Lite0 see stack_blocks' plate / stack cue? Linear probes per stage.

    .venv/bin/python benchmarks/probe_plate_cue.py --train DEMOS/train/stack_blocks \
        --test DEMOS/test/stack_blocks [--view front] [--subsets 3,10] [--out f.json]

stack_blocks' image-dependent boundaries are "lift the C block" -> "move the C block above the
plate" (the first block) or "... above the stack of C blocks" (the others): goal and previous
instruction are the same, only a block on the plate tells them apart. For the image at each such
segment start (native episodes, e.g. the stage cache's ``demos/<key>/<split>/stack_blocks``), the
script takes the output of the last block at each feature-map size of EfficientNet-Lite0 (the
planner's frozen tower uses the 7 x 7 head) and fits a logistic probe (standardised, spatial mean
or max) on the train episodes, scored on the test episodes beside the majority-class rate; with
``--subsets`` also on random subsets of K train episodes (the planner's finetuning sees M = 3).
Figures are printed (never asserted); ``--out`` writes them as JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from rdd.atomic import write_text_atomic


def boundary_images(root: Path, view: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Images at the "lift -> move above" segment starts under ``root``; label: the plate (first block)."""
    from planner.dataset import examples_from_episode
    from rdd.data.native import is_native_episode, load_episode, natural_key

    dirs = sorted((d for d in Path(root).iterdir() if is_native_episode(d)), key=natural_key)
    if not dirs:
        raise FileNotFoundError(f"--train/--test {root}: no native episode directories")
    images, labels, episodes = [], [], []
    for d in dirs:
        for ex in examples_from_episode(load_episode(d), view=view):
            if (ex.previous_instruction or "").startswith("lift") and ex.target.startswith("move"):
                images.append(ex.image)
                labels.append("above the plate" in ex.target)
                episodes.append(d.name)
    if not images:
        raise ValueError(f"{root}: no 'lift ...' -> 'move ... above ...' boundary (not stack_blocks?)")
    return np.stack(images), np.array(labels), episodes


def stage_features(images: np.ndarray) -> dict[str, np.ndarray]:
    """Per feature-map size (and the head), spatial mean and max of the last block's output."""
    import torch

    from rdd.encoders.effnet_lite0 import build, preprocess

    net = build().model.eval()
    maps: dict[str, torch.Tensor] = {}
    with torch.no_grad():
        h = net._swish(net._bn0(net._conv_stem(preprocess(images))))
        for block in net._blocks:
            h = block(h)
            maps[f"{h.shape[-1]}x{h.shape[-1]}x{h.shape[1]}"] = h
        maps["head 7x7x1280 (the planner's tower)"] = net._swish(net._bn1(net._conv_head(h)))
    out = {}
    for name, m in maps.items():
        out[f"{name} mean"] = m.mean(dim=(2, 3)).numpy()
        out[f"{name} max"] = m.amax(dim=(2, 3)).numpy()
    return out


def probe(train_x: np.ndarray, train_y: np.ndarray, test_x: np.ndarray, test_y: np.ndarray, c: float = 1.0) -> float:
    """Test accuracy of a standardised logistic regression fitted on the train features."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    clf = make_pipeline(StandardScaler(), LogisticRegression(C=c, max_iter=5000))
    return float(clf.fit(train_x, train_y).score(test_x, test_y))


def main(argv: list[str] | None = None) -> int:
    """CLI entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--train", type=Path, required=True, help="folder of native stack_blocks episodes")
    parser.add_argument("--test", type=Path, required=True, help="folder of held-out native stack_blocks episodes")
    parser.add_argument("--view", default="front")
    parser.add_argument("--subsets", default="3,10", help="K train episodes per random subset (10 draws each)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    tr_img, tr_y, tr_ep = boundary_images(args.train, args.view)
    te_img, te_y, _ = boundary_images(args.test, args.view)
    majority = max(te_y.mean(), 1 - te_y.mean())
    print(f"{len(tr_y)} train boundaries ({len(set(tr_ep))} episodes), {len(te_y)} test; "
          f"majority-class rate on test {majority:.3f}")
    ks = [int(k) for k in args.subsets.split(",") if k]
    # one pass of the network over train and test images together, split afterwards
    both = stage_features(np.concatenate([tr_img, te_img]))
    f_tr = {k: v[:len(tr_y)] for k, v in both.items()}
    f_te = {k: v[len(tr_y):] for k, v in both.items()}
    rng = np.random.default_rng(0)
    names = sorted(set(tr_ep))
    rows = []
    print(f"{'features':44s} {'all':>6s} " + " ".join(f"{'K=' + str(k):>6s}" for k in ks))
    for name in f_tr:
        row = {"features": name, "all": probe(f_tr[name], tr_y, f_te[name], te_y)}
        for k in ks:
            accs = []
            while len(accs) < 10:
                pick = set(rng.choice(len(names), size=min(k, len(names)), replace=False).tolist())
                mask = np.array([names.index(e) in pick for e in tr_ep])
                if len(set(tr_y[mask].tolist())) == 2:
                    accs.append(probe(f_tr[name][mask], tr_y[mask], f_te[name], te_y))
            row[f"K={k}"] = float(np.mean(accs))
        rows.append(row)
        print(f"{name:44s} {row['all']:6.3f} " + " ".join(f"{row[f'K={k}']:6.3f}" for k in ks), flush=True)
    if args.out:
        write_text_atomic(args.out, json.dumps({"majority": majority, "train": len(tr_y), "test": len(te_y),
                                                "view": args.view, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
