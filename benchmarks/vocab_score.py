"""Cost of scoring a trajectory vocabulary per (scene, entry), PDMS v1.1 or EPDMS v2.2, against our per-trajectory
scorer on the same scenes (one core: the process pins itself to ``--cpu``; CPU time of this process, wall time beside
it, and the load average, since a shared machine inflates both).

OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/vocab_score.py --metric pdms@navsim-1.1 --sizes 256 2048 8192

Scenes: the first ``--scenes`` scenes of one synthetic NAVSIM log (``lead_s2r.synthetic.navsim``, converted with maps,
as the quickstart makes them), PDM-Closed planned beforehand (``vocab score`` plans it once per scene, the cost of
one entry). Vocabulary: ``--sizes`` entries in GTRS's layout (40 poses at 0.1 s) spanning speeds 0-20 m/s, curvatures
of +-0.15 1/m and accelerations of +-3 m/s^2, seeded. ``score_vocabulary`` is timed whole, scene-shared work
included (observation, drivable map, red lights); the per-trajectory figure is one ``score_proposals`` call per entry
with the observation and drivable map prebuilt (what ``score`` pays per sample), over ``--singles`` entries.
``--memory N``: afterwards, the peak resident memory the process grew by while scoring N entries on one scene.
"""

import argparse
import os
import resource
import tempfile
from functools import partial
from pathlib import Path

import numpy as np
from cpu_time import cpu_times_ms, wall_and_cpu

from lead_s2r.convert import convert
from lead_s2r.scoring.pdm import score_proposals, score_vocabulary
from lead_s2r.scoring.pdm.map_flags import DrivableMap
from lead_s2r.scoring.pdm.observation import V2_STEPS, log_observation
from lead_s2r.scoring.pdm.pdm_closed import plan_reference
from lead_s2r.scoring.pdm.sample import scene_from_sample
from lead_s2r.scoring.pdm.scene import PDMScene
from lead_s2r.scoring.pdm.score import EPDMS_METRIC, METRIC, METRICS
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim
from lead_s2r_adapters.navsim import NavsimAdapter


def vocabulary(size: int, seed: int = 0) -> np.ndarray:
    """``(size, 40, 3)`` float32 poses: random speed, curvature and acceleration profiles, integrated at 0.1 s."""
    rng = np.random.default_rng(seed)
    dt = 0.1
    speed0 = rng.uniform(0.0, 20.0, (size, 1))
    accel = rng.uniform(-3.0, 3.0, (size, 1))
    curvature = rng.uniform(-0.15, 0.15, (size, 1)) * rng.uniform(0.0, 1.0, (size, 1)) ** 2
    speed = np.clip(speed0 + accel * dt * np.arange(1, 41), 0.0, None)
    heading = np.cumsum(speed * curvature * dt, axis=1)
    x = np.cumsum(speed * np.cos(heading) * dt, axis=1)
    y = np.cumsum(speed * np.sin(heading) * dt, axis=1)
    return np.stack([x, y, heading], -1).astype(np.float32)


def scenes(count: int) -> list[PDMScene]:
    with tempfile.TemporaryDirectory() as folder:
        raw, out = Path(folder) / "raw", Path(folder) / "data"
        navsim.generate(raw, count=2, seed=0)
        assert convert(NavsimAdapter(maps=str(raw / "maps")), raw, out, progress=False).ok
        samples = list(read_samples(out, fields=("scoring", "boxes", "agents_future", "future")))
    return [scene_from_sample(sample) for sample in samples[:: max(1, len(samples) // count)][:count]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--metric", choices=METRICS, default=METRIC)
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 2048, 8192])
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--singles", type=int, default=16)
    parser.add_argument("--cpu", type=int, default=0, help="the core to pin this process to")
    parser.add_argument("--memory", type=int, default=0, help="entries for the peak-memory check (0: skip it)")
    args = parser.parse_args()
    os.sched_setaffinity(0, {args.cpu})
    chosen = scenes(args.scenes)
    references = [plan_reference(scene) for scene in chosen]
    largest = vocabulary(max(args.sizes))
    v2 = args.metric == EPDMS_METRIC
    single_us = []
    for scene, reference in zip(chosen, references, strict=True):
        cached = {
            "observation": log_observation(scene, V2_STEPS, replay=True) if v2 else log_observation(scene),
            "drivable_map": DrivableMap.from_scene(scene),
        }
        for v in range(args.singles):
            entry = largest[v : v + 1]
            call = partial(score_proposals, scene, entry, 0.1, reference, args.metric, **cached)
            single_us.append(1e3 * float(np.median(cpu_times_ms(call, 3))))
    single = float(np.median(single_us))
    print(f"{args.metric}, {len(chosen)} scenes, core {args.cpu}; per-trajectory scorer: {single:.0f} us per call")
    print("entries | us per (scene, entry), CPU | wall | vs per-trajectory (CPU)")
    for size in args.sizes:
        cpu, wall = [], []
        for scene, reference in zip(chosen, references, strict=True):
            _, wall_s, cpu_s = wall_and_cpu(
                partial(score_vocabulary, scene, largest[:size], 0.1, reference, args.metric)
            )
            cpu.append(1e6 * cpu_s / size)
            wall.append(1e6 * wall_s / size)
        us = float(np.median(cpu))
        print(f"{size:7d} | {us:26.1f} | {float(np.median(wall)):4.1f} | {single / us:6.1f}x")
    if args.memory:
        entries = vocabulary(args.memory, seed=1)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB; grown 0: it stayed under the peak
        score_vocabulary(chosen[0], entries, 0.1, references[0], args.metric)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        print(
            f"{args.memory} entries on one scene: peak memory grew {(peak - before) / 1024:.0f} MB, "
            f"process peak {peak / 1024:.0f} MB"
        )
    print("load average (1, 5, 15 min): " + ", ".join(f"{load:.1f}" for load in os.getloadavg()))


if __name__ == "__main__":
    main()
