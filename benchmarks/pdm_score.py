"""Cost of one scene's PDMS v1.1 (reference + agent: interpolation, simulation, scoring) and how it grows with the
proposals per scene (one core, CPU time of this process).

.venv/bin/python benchmarks/pdm_score.py --proposals 1 16 256 --repeats 20

Scenes are the official golden cases (``tests/data/navsim_pdms_v11_official.json.gz``), timed as the official
figure was: per scene the mean over its trajectories of one call, then the median over scenes. The observation and
the drivable map are built once per scene beforehand (the metric cache, excluded as in the official figure).
"""

import argparse
import sys
import time
from functools import partial
from pathlib import Path
from statistics import median

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from pdm_golden import golden_scene, load_golden, reference_poses

from lead_s2r.scoring.pdm.map_flags import DrivableMap
from lead_s2r.scoring.pdm.observation import log_observation
from lead_s2r.scoring.pdm.score import score_proposals


def cpu_ms(function, repeats: int) -> float:
    """Median CPU time in ms after one warm-up call."""
    function()
    times = []
    for _ in range(repeats):
        started = time.process_time()
        function()
        times.append(time.process_time() - started)
    return 1e3 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--proposals", type=int, nargs="+", default=[1, 16, 256])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    golden = load_golden()
    per_scene = {count: [] for count in args.proposals}
    for case in golden["scenes"]:
        scene = golden_scene(case)
        cached = {"observation": log_observation(scene), "drivable_map": DrivableMap.from_scene(scene)}
        reference = reference_poses(case)
        for count in args.proposals:
            calls = []
            for trajectory in case["trajectories"]:
                proposals = np.repeat(np.asarray(trajectory["poses"], np.float64)[None], count, axis=0)
                call = partial(score_proposals, scene, proposals, trajectory["interval_s"], reference, **cached)
                calls.append(cpu_ms(call, args.repeats))
            per_scene[count].append(float(np.mean(calls)))
    official = 1e3 * golden["official_seconds_per_scene"]
    print(f"official v1.1, reference + 1 agent: {official:.2f} ms per scene (wall time, from the golden file)")
    print("proposals  ms per scene (median over scenes)  ms per proposal  vs official")
    for count, times in per_scene.items():
        ms = median(times)
        print(f"{count:9d}  {ms:32.2f}  {ms / count:15.3f}  {official / ms:9.1f}x")


if __name__ == "__main__":
    main()
