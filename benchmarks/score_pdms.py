"""Scenes per second of PDMS v1.1 on one core: PDM-Closed's reference, and scoring 1 / 16 / 256 proposals per scene.

Run: ``.venv/bin/python benchmarks/score_pdms.py [--data CONVERTED_NAVSIM] [--scenes N]``. Without ``--data`` the
synthetic NAVSIM set is generated and converted (with maps) into a temporary folder. Threads are pinned to 1 before
numpy loads. Per scene, timed separately (the scene is built from the sample beforehand, as a metric cache would be):

* ``reference``: :func:`plan_reference` (15 IDM proposals unrolled, simulated and scored, best extended to 5 s);
* ``agent``: :func:`score_proposals` of N proposals beside the cached reference: interpolation, simulation of
  N + 1 trajectories, observation and map flags, sub-scores. NAVSIM's own ``pdm_score`` scores 1 proposal with a
  prebuilt observation and drivable map; the ``prebuilt`` rows pass those in too, the others build them per call.
"""

import one_core  # noqa: F401  (first: pins BLAS threads before numpy loads)

# isort: split
import argparse
import statistics
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from cpu_time import wall_times_ms

from lead_s2r.convert import convert
from lead_s2r.registry import get_adapter
from lead_s2r.scoring.baselines import predict_human
from lead_s2r.scoring.navsim.proposals import proposal_of
from lead_s2r.scoring.pdm.map_flags import DrivableMap
from lead_s2r.scoring.pdm.observation import log_observation
from lead_s2r.scoring.pdm.pdm_closed import plan_reference
from lead_s2r.scoring.pdm.sample import scene_from_sample
from lead_s2r.scoring.pdm.score import score_proposals
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim as synth

PROPOSALS = (1, 16, 256)


def synthetic_data(folder: Path) -> Path:
    """The synthetic NAVSIM logs, converted with maps."""
    raw, out = folder / "raw", folder / "data"
    synth.generate(raw)
    adapter = get_adapter("navsim", scene_filter=str(raw / "scene_filters" / "navmini.yaml"), maps=str(raw / "maps"))
    result = convert(adapter, raw, out, workers=1, force=True)
    if not result.ok:
        raise RuntimeError(f"conversion failed: {result.errors}")
    return out


def proposals_around(human: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` proposals (count, K, 3): the human trajectory, then lateral shifts and speed scalings of it."""
    scale = np.r_[1.0, rng.uniform(0.5, 1.3, count - 1)]
    shift = np.r_[0.0, rng.uniform(-2.0, 2.0, count - 1)]
    out = np.repeat(human[None], count, axis=0)
    out[..., :2] *= scale[:, None, None]
    out[..., 1] += shift[:, None] * np.linspace(0.0, 1.0, human.shape[0])[None]
    return out


def median_ms(run: Callable[[], object], repeats: int) -> float:
    return float(np.median(wall_times_ms(run, repeats, warm_up=False)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data", type=Path, default=None, help="a converted NAVSIM folder (with maps)")
    parser.add_argument("--scenes", type=int, default=21)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        data = args.data or synthetic_data(Path(folder))
        samples = [s for _, s in zip(range(args.scenes), read_samples(data), strict=False)]
    scenes = [scene_from_sample(sample) for sample in samples]
    humans = [proposal_of(predict_human(sample)) for sample in samples]
    rng = np.random.default_rng(0)
    print(f"PDMS v1.1 on one core, {len(scenes)} scenes; median over scenes of the median of {args.repeats} runs")
    reference_ms = [median_ms(lambda s=scene: plan_reference(s), args.repeats) for scene in scenes]
    references = [plan_reference(scene) for scene in scenes]
    report("reference (PDM-Closed)", reference_ms)
    for count in PROPOSALS:
        batches = [proposals_around(poses, count, rng) for poses, _ in humans]
        for prebuilt in (False, True):
            timings = []
            for scene, (_, interval), batch, reference in zip(scenes, humans, batches, references, strict=True):
                extra = {"observation": log_observation(scene), "drivable_map": DrivableMap.from_scene(scene)}
                extra = extra if prebuilt else {}

                def run(scene=scene, batch=batch, interval=interval, reference=reference, extra=extra) -> None:
                    score_proposals(scene, batch, interval, reference=reference, **extra)

                timings.append(median_ms(run, args.repeats))
            report(f"agent, {count} proposal(s){', prebuilt' if prebuilt else ''}", timings)


def report(label: str, timings_ms: list[float]) -> None:
    median = statistics.median(timings_ms)
    print(f"{label:<36} {median:8.2f} ms/scene  {1e3 / median:8.1f} scenes/s")


if __name__ == "__main__":
    main()
