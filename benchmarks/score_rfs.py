"""Frames per second of RFS scoring on one core: the vectorised kernel, rater padding, and the whole scorer.

Run: ``.venv/bin/python benchmarks/score_rfs.py [--frames N]``. Threads are pinned to 1 before numpy loads.
"""

import one_core  # noqa: F401  (first: pins BLAS threads before numpy loads)

# isort: split
import argparse
from collections.abc import Callable

import numpy as np
from cpu_time import wall_times_ms

from lead_s2r.predictions import Prediction, regular_grid
from lead_s2r.scoring.rfs import RFSConfig, RFSScorer, pad_raters, rater_feedback_score


def synthetic_frames(count: int, seed: int = 0) -> dict[str, np.ndarray]:
    """WOD-like frames: 2-3 raters of 11-20 points around a straight drive, predictions near them."""
    rng = np.random.default_rng(seed)
    t = regular_grid(4, 5)
    speed = rng.uniform(0, 20, count)
    heading = rng.normal(0, 0.2, (count, 3, 1))
    base = speed[:, None, None] * t[None, None, :]
    raters = np.stack([base * np.cos(heading), base * np.sin(heading)], axis=-1)
    lengths = rng.integers(11, 21, (count, 3))
    counts = rng.integers(2, 4, count)
    labels = rng.uniform(0, 10, (count, 3))
    predictions = raters[:, :1] + rng.normal(0, 1.0, (count, 1, 20, 2))
    return {"raters": raters, "lengths": lengths, "counts": counts, "labels": labels, "predictions": predictions,
            "speed": speed}  # fmt: skip


def rate(label: str, frames: int, run: Callable[[], object], repeats: int = 3) -> None:
    best = wall_times_ms(run, repeats, warm_up=False).min() / 1e3
    print(f"{label:<52} {frames / best:>12,.0f} frames/s  ({best * 1e3:8.1f} ms for {frames:,} frames)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=100_000)
    parser.add_argument("--chunk", type=int, default=8192, help="frames per kernel call")
    args = parser.parse_args()
    data = synthetic_frames(args.frames)
    config = RFSConfig()
    padded, labels = pad_raters(data["raters"], data["lengths"], data["counts"], data["labels"], config)
    probabilities = np.ones((args.frames, 1))
    chunks = [slice(i, i + args.chunk) for i in range(0, args.frames, args.chunk)]

    def kernel() -> None:
        for c in chunks:
            rater_feedback_score(data["predictions"][c], probabilities[c], padded[c], labels[c], data["speed"][c])

    def padding_and_kernel() -> None:
        for c in chunks:
            raters, rater_labels = pad_raters(
                data["raters"][c], data["lengths"][c], data["counts"][c], data["labels"][c], config
            )
            rater_feedback_score(data["predictions"][c], probabilities[c], raters, rater_labels, data["speed"][c])

    print(f"RFS on one core, {args.frames:,} frames, 4 Hz x 20 points, 3 raters, 1 inference, chunks of {args.chunk}")
    rate("kernel rater_feedback_score (padded arrays)", args.frames, kernel)
    rate("pad_raters + kernel", args.frames, padding_and_kernel)

    count = min(args.frames, 20_000)
    grid = regular_grid(4, 5).astype(np.float32)
    yaw = np.zeros(20, np.float32)
    predictions = [
        Prediction(f"k{b}", "wod_e2e", grid, data["predictions"][b, 0].astype(np.float32), yaw) for b in range(count)
    ]
    samples = []
    for b in range(count):
        valid = data["counts"][b]
        trajectories = data["raters"][b, :valid].astype(np.float32)
        for p in range(valid):
            trajectories[p, data["lengths"][b, p] :] = np.nan
        raters = {"trajectories": trajectories, "scores": data["labels"][b, :valid].astype(np.float32),
                  "lengths": data["lengths"][b, :valid].astype(np.int32)}  # fmt: skip
        samples.append({"__key__": f"k{b}", "meta": {"dataset": "wod_e2e", "ego": {"speed": data["speed"][b]}},
                        "raters": raters})  # fmt: skip
    rate("RFSScorer.score (join, grid, padding, table)", count, lambda: RFSScorer().score(predictions, samples))


if __name__ == "__main__":
    main()
