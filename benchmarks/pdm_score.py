"""Cost of one scene's PDMS v1.1 or EPDMS v2.2 (reference + agent: interpolation, simulation, scoring; v2.2 also the
human trajectory of the penalty filter) and how it grows with the proposals per scene (one core, CPU time of this
process).

.venv/bin/python benchmarks/pdm_score.py --metric epdms@navsim-2.2 --proposals 1 16 256 --repeats 20

Scenes are the official golden cases of the metric (``tests/data/navsim_pdms_v11_official.json.gz``,
``navsim_epdms_v22_official.json.gz``), timed as the official figure was: per scene the mean over its trajectories of
one call, then the median over scenes. The observation and the drivable map are built once per scene beforehand (the
metric cache, excluded as in the official figure); EC's previous frames are left out, as the official figure leaves
out the aggregation that computes EC.
"""

import argparse
import sys
from functools import partial
from pathlib import Path
from statistics import median

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from cpu_time import cpu_times_ms
from pdm_golden import GOLDEN, GOLDEN_V22, golden_scene, load_golden, reference_poses

from lead_s2r.scoring.pdm.map_flags import DrivableMap
from lead_s2r.scoring.pdm.observation import V2_STEPS, log_observation
from lead_s2r.scoring.pdm.score import EPDMS_METRIC, METRIC, METRICS, score_proposals

GOLDEN_FILES = {METRIC: GOLDEN, EPDMS_METRIC: GOLDEN_V22}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--proposals", type=int, nargs="+", default=[1, 16, 256])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--metric", choices=METRICS, default=METRIC)
    args = parser.parse_args()
    golden = load_golden(GOLDEN_FILES[args.metric])
    per_scene = {count: [] for count in args.proposals}
    for case in golden["scenes"]:
        scene = golden_scene(case)
        v2 = args.metric == EPDMS_METRIC
        cached = {
            "metric": args.metric,
            "observation": log_observation(scene, V2_STEPS, replay=True) if v2 else log_observation(scene),
            "drivable_map": DrivableMap.from_scene(scene),
        }
        reference = reference_poses(case)
        for count in args.proposals:
            calls = []
            for trajectory in case["trajectories"]:
                proposals = np.repeat(np.asarray(trajectory["poses"], np.float64)[None], count, axis=0)
                call = partial(score_proposals, scene, proposals, trajectory["interval_s"], reference, **cached)
                calls.append(float(np.median(cpu_times_ms(call, args.repeats))))
            per_scene[count].append(float(np.mean(calls)))
    official = 1e3 * golden["official_seconds_per_scene"]
    print(f"official {args.metric}, one pdm_score call: {official:.2f} ms per scene (wall time, from the golden file)")
    print("proposals  ms per scene (median over scenes)  ms per proposal  vs official")
    for count, times in per_scene.items():
        ms = median(times)
        print(f"{count:9d}  {ms:32.2f}  {ms / count:15.3f}  {official / ms:9.1f}x")


if __name__ == "__main__":
    main()
