"""CPU cost of LEAD's CARLA labels built from one generated LEAD frame: the 13-class BEV label and the CenterNet
targets of LEAD's 8 box classes, on LEAD's leaderboard BEV (384 x 320, CenterNet 96 x 80).

.venv/bin/python benchmarks/lead_labels.py --boxes 90 --calls 200

The frame's boxes are repeated to ``--boxes`` rows (LEAD encodes at most 90).
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np
from cpu_time import wall_times_ms

from lead_s2r.data.lead_centernet import lead_centernet_targets
from lead_s2r.data.lead_labels import bev_labels, lead_bev_labels, lead_box_classes
from lead_s2r.models.config import CARLA_BEV
from lead_s2r.registry import get_adapter
from lead_s2r.synthetic.carla_lead import generate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--boxes", type=int, default=90)
    parser.add_argument("--calls", type=int, default=200)
    args = parser.parse_args()
    src = Path(tempfile.mkdtemp())
    generate(src, count=1, seed=7, frames=1)
    adapter = get_adapter("carla_lead")
    sample = next(s for log in adapter.list_logs(src) for s in adapter.iter_samples(log))
    boxes = np.resize(sample["boxes"], (args.boxes, 10))
    hdmap = bev_labels(sample["bev_semantic"], sample["meta"]["bev"], CARLA_BEV)
    lights = np.full(len(boxes), -1)  # no traffic light affects the ego
    classes = lead_box_classes(boxes[:, 9].astype(np.int64), True, lights)
    bev_ms = wall_times_ms(lambda: lead_bev_labels(hdmap, boxes, CARLA_BEV, True, lights), args.calls).mean()
    boxes_ms = wall_times_ms(lambda: lead_centernet_targets(boxes, classes, CARLA_BEV, 8, 12), args.calls).mean()
    print(f"lead_bev_labels: {bev_ms:.2f} ms, lead_centernet_targets: {boxes_ms:.2f} ms ({args.boxes} boxes)")


if __name__ == "__main__":
    main()
