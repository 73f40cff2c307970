"""The training list of the tracking split (lab/log.md 63): every take in the shared motion capture except the
held-out ones (lab/splits/heldout-tracking.txt) and any take that is the same capture as a held-out one in another
form.

The same CMU capture reaches the shared folder up to three times (ASF/AMC, the Character Creator BVH, the
exponential-map set, which renames its takes by action). Two files are taken for one capture when their lengths
agree within 10% and the root's speed at 30 Hz correlates above 0.9 at the best lag of up to 0.2 s (a scale-free
test: the forms differ in units and axes). Known twins score 0.87-1.0 (02_05 in ASF/AMC and BVH 0.87, since the
conversions trim differently), and walks of one gait score 0.8-0.9 with each other, so the test is conservative:
a near-twin of a held-out take is left out of training too, at the cost of a few walks.

    python lab/experiments/tracking_split.py ../shared/mocap --out lab/splits/train-tracking.txt
"""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

SUFFIXES = (".amc", ".bvh", ".txt")
MIN_CORRELATION = 0.9
MAX_LENGTH_GAP = 0.1


def _to_30hz(points: np.ndarray, fps: float) -> np.ndarray:
    t = np.arange(len(points)) / fps
    grid = np.arange(0.0, t[-1], 1 / 30)
    return np.stack([np.interp(grid, t, points[:, i]) for i in range(points.shape[1])], axis=1)


def root_path(path: Path) -> np.ndarray | None:
    """(T, 3) root positions at 30 Hz in the file's own units and axes, or None for a file that is no capture."""
    if path.suffix == ".amc":
        rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("root ")]
        return _to_30hz(np.array(rows, dtype=float), 120)
    if path.suffix == ".bvh":
        text = path.read_text()
        head, motion = text.split("Frame Time:")
        frame_time = float(motion.split()[0])
        values = np.array([line.split()[:3] for line in motion.strip().splitlines()[1:]], dtype=float)
        if "CC_Base" in head:  # the Character Creator takes open with a T-pose frame
            values = values[1:]
        return _to_30hz(values, 1 / frame_time)
    if "expmap" in path.parts:
        return _to_30hz(np.loadtxt(path, delimiter=",", usecols=(0, 1, 2))[1:], 120)  # line 1: the rest pose
    return None


def same_capture(a: np.ndarray, b: np.ndarray) -> float:
    """Best correlation of the two root speed profiles within +-6 frames of lag (0 where the lengths differ)."""
    sa, sb = (np.linalg.norm(np.diff(p, axis=0), axis=1) for p in (a, b))
    if abs(len(sa) - len(sb)) > MAX_LENGTH_GAP * max(len(sa), len(sb)):
        return 0.0
    n = min(len(sa), len(sb)) - 12
    if n < 10:
        return 0.0
    scores = [np.corrcoef(sa[6:6 + n], sb[6 + lag:6 + lag + n])[0, 1] for lag in range(-6, 7)
              if 6 + lag + n <= len(sb)]
    return float(np.nanmax(scores))


def all_takes(root: Path) -> list[str]:
    takes = [p for p in sorted(root.rglob("*")) if p.suffix in SUFFIXES and p.is_file()]
    takes = [p for p in takes if not (p.suffix == ".txt" and p.parent.name not in ("motions",) and "expmap" not in
                                      p.parts)]  # READMEs and notes are no takes
    return [str(p.relative_to(root)) for p in takes]


def read_split(path: Path) -> list[str]:
    return [re.split(r"\s+#", line)[0].strip() for line in path.read_text().splitlines()
            if line.strip() and not line.startswith("#")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mocap", type=Path, help="the shared motion capture folder")
    ap.add_argument("--heldout", type=Path, default=Path("lab/splits/heldout-tracking.txt"))
    ap.add_argument("--out", type=Path, default=Path("lab/splits/train-tracking.txt"))
    args = ap.parse_args()
    heldout = read_split(args.heldout)
    missing = [h for h in heldout if not (args.mocap / h).is_file()]
    if missing:
        raise SystemExit(f"{args.heldout}: no such take under {args.mocap}: {', '.join(missing)}")
    takes = all_takes(args.mocap)
    cmu = [t for t in takes if t.startswith("cmu/") and "bvh-daz" not in t]  # the Daz takes are other subjects
    paths = {t: root_path(args.mocap / t) for t in cmu}
    excluded: dict[str, tuple[str, float]] = {}
    for h in heldout:
        if h not in paths:
            continue
        for t in cmu:
            if t in heldout or t == h:
                continue
            score = same_capture(paths[h], paths[t])
            if score > MIN_CORRELATION:
                excluded[t] = (h, score)
    lines = ["# Training list of the tracking split (lab/log.md 63): every take under ../shared/mocap except the",
             f"# held-out ones ({args.heldout}) and the same captures in another form.",
             "# Written by lab/experiments/tracking_split.py; paths relative to ../shared/mocap."]
    lines += [f"# excluded, a possible twin of held-out {h} (root-speed correlation {s:.3f}): {t}"
              for t, (h, s) in sorted(excluded.items())]
    train = [t for t in takes if t not in heldout and t not in excluded]
    lines += train
    args.out.write_text("\n".join(lines) + "\n")
    print(f"{len(takes)} takes: {len(heldout)} held out, {len(excluded)} excluded as their twins, "
          f"{len(train)} to train on -> {args.out}")


if __name__ == "__main__":
    main()
