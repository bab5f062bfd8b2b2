"""Cost of one scene's PDMS v1.1 or EPDMS v2.2 (reference + agent: interpolation, simulation, scoring; v2.2 also the
human trajectory of the penalty filter), how it grows with the proposals per scene, and PDM-Closed's reference (one
core, CPU time of this process).

.venv/bin/python benchmarks/pdm_score.py --metric epdms@navsim-2.2 --proposals 1 16 256 --repeats 20
.venv/bin/python benchmarks/pdm_score.py --data converted/navsim --scenes 21 --per-call

Scenes are the official golden cases of the metric (``tests/data/navsim_pdms_v11_official.json.gz``,
``navsim_epdms_v22_official.json.gz``), timed as the official figure was: per scene the mean over its trajectories of
one call, then the median over scenes. With ``--data``, the first ``--scenes`` samples of a converted NAVSIM folder
(with maps), each scored with its logged future as the proposal beside its PDM-Closed reference. The observation and
the drivable map are built once per scene beforehand (the metric cache, excluded as in the official figure) unless
``--per-call``; EC's previous frames are left out, as the official figure leaves out the aggregation that computes
EC. PDM-Closed's reference (``plan_reference``: 15 IDM proposals unrolled, simulated and scored) is timed per scene.
"""

import one_core  # noqa: F401  (first: pins BLAS threads before numpy loads)

# isort: split
import argparse
import sys
from functools import partial
from itertools import islice
from pathlib import Path
from statistics import median

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from cpu_time import cpu_times_ms
from pdm_golden import GOLDEN, GOLDEN_V22, golden_scene, load_golden, reference_poses

from lead_s2r.scoring.baselines import predict_human
from lead_s2r.scoring.navsim.proposals import proposal_of
from lead_s2r.scoring.pdm.map_flags import DrivableMap
from lead_s2r.scoring.pdm.observation import V2_STEPS, log_observation
from lead_s2r.scoring.pdm.pdm_closed import plan_reference
from lead_s2r.scoring.pdm.sample import scene_from_sample
from lead_s2r.scoring.pdm.score import EPDMS_METRIC, METRIC, METRICS, score_proposals
from lead_s2r.shards import read_samples

GOLDEN_FILES = {METRIC: GOLDEN, EPDMS_METRIC: GOLDEN_V22}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--proposals", type=int, nargs="+", default=[1, 16, 256])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--metric", choices=METRICS, default=METRIC)
    parser.add_argument("--data", type=Path, help="a converted NAVSIM folder (with maps) instead of the golden scenes")
    parser.add_argument("--scenes", type=int, default=21, help="samples of --data scored")
    parser.add_argument("--per-call", action="store_true", help="build the observation and drivable map per call")
    args = parser.parse_args()
    golden = None if args.data else load_golden(GOLDEN_FILES[args.metric])
    if golden is not None:
        cases = [(golden_scene(case), reference_poses(case), case["trajectories"]) for case in golden["scenes"]]
    else:
        samples = islice(read_samples(args.data, fields=("scoring", "boxes", "agents_future", "future")), args.scenes)
        scenes = [(scene_from_sample(sample), proposal_of(predict_human(sample))) for sample in samples]
        cases = [(scene, plan_reference(scene), [{"poses": p, "interval_s": i}]) for scene, (p, i) in scenes]
    per_scene = {count: [] for count in args.proposals}
    reference_ms = []
    for scene, reference, trajectories in cases:
        reference_ms.append(float(np.median(cpu_times_ms(partial(plan_reference, scene), args.repeats))))
        v2 = args.metric == EPDMS_METRIC
        cached = {}  # the metric cache, built once per scene unless --per-call
        if not args.per_call:
            cached["observation"] = log_observation(scene, V2_STEPS, replay=True) if v2 else log_observation(scene)
            cached["drivable_map"] = DrivableMap.from_scene(scene)
        for count in args.proposals:
            calls = []
            for trajectory in trajectories:
                proposals = np.repeat(np.asarray(trajectory["poses"], np.float64)[None], count, axis=0)
                call = partial(
                    score_proposals, scene, proposals, trajectory["interval_s"], reference, args.metric, **cached
                )
                calls.append(float(np.median(cpu_times_ms(call, args.repeats))))
            per_scene[count].append(float(np.mean(calls)))
    print(f"{len(cases)} scenes; PDM-Closed reference (plan_reference): {median(reference_ms):.2f} ms per scene")
    if golden is not None:
        official = 1e3 * golden["official_seconds_per_scene"]
        print(f"official {args.metric}, one pdm_score call: {official:.2f} ms per scene (wall time, golden file)")
    print("proposals  ms per scene (median over scenes)  ms per proposal  vs official")
    for count, times in per_scene.items():
        ms = median(times)
        versus = "" if golden is None else f"{official / ms:9.1f}x"
        print(f"{count:9d}  {ms:32.2f}  {ms / count:15.3f}  {versus}")


if __name__ == "__main__":
    main()
