"""Cost of NAVSIM's trajectory interpolation + LQR/bicycle simulation per scene, by proposals per scene (one core).

.venv/bin/python benchmarks/pdm_simulation.py --proposals 1 2 16 256 --repeats 50

A scene's PDMS simulates 2 proposals (PDM-Closed reference + agent); a planner's candidate set many more.
Proposals are 8 poses at 0.5 s on arcs of mixed speed and curvature, some braking to a stop. The first call
compiles the simulator (or loads numba's cache) and is left out.
"""

import argparse
from functools import partial

import numpy as np
from cpu_time import cpu_times_ms

from lead_s2r.scoring.pdm.interpolation import interpolate_proposals
from lead_s2r.scoring.pdm.simulation import simulate_proposals


def proposals(count: int, seed: int = 0) -> np.ndarray:
    """``(count, 8, 3)`` ego-frame poses at 0.5 s: arcs with speeds 0..15 m/s and curvatures up to 1/20 m."""
    rng = np.random.default_rng(seed)
    t = 0.5 * np.arange(1, 9)
    speed = rng.uniform(0.0, 15.0, (count, 1))
    decel = np.where(rng.random((count, 1)) < 0.25, speed / 4.0, 0.0)  # a quarter brake to a stop at 4 s
    distance = speed * t - decel * t**2 / 2
    heading = rng.uniform(-0.05, 0.05, (count, 1)) * distance
    step = np.diff(np.concatenate([np.zeros((count, 1)), distance], axis=1), axis=1)
    mid = heading - np.diff(np.concatenate([np.zeros((count, 1)), heading], axis=1), axis=1) / 2
    x, y = np.cumsum(step * np.cos(mid), axis=1), np.cumsum(step * np.sin(mid), axis=1)
    return np.stack([x, y, heading], axis=-1)


def timed(function, repeats: int) -> tuple[float, float]:
    """Median and minimum CPU time of this process in ms after one warm-up call (less skewed by other load)."""
    times = cpu_times_ms(function, repeats)
    return float(np.median(times)), float(np.min(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--proposals", type=int, nargs="+", default=[1, 2, 16, 256])
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args()
    velocity, acceleration = np.array([8.0, 0.0]), np.array([0.3, 0.0])
    print("proposals  interpolation ms (median / min)  simulation ms (median / min)  ms per proposal")
    for count in args.proposals:
        poses = proposals(count)
        targets = interpolate_proposals(poses, 0.5)
        interp = timed(partial(interpolate_proposals, poses, 0.5, t0_us=1624385736449714), args.repeats)
        sim = timed(partial(simulate_proposals, targets, velocity, acceleration), args.repeats)
        per = (interp[0] + sim[0]) / count
        print(f"{count:9d}  {interp[0]:13.3f} / {interp[1]:.3f}  {sim[0]:19.3f} / {sim[1]:.3f}  {per:15.3f}")


if __name__ == "__main__":
    main()
