"""How long ``lead-s2r score --split/--tag`` takes to get its samples: every sample of the folder decoded and the
split kept after (the baseline, webdataset's reader), against the manifest choosing first and only those decoded,
and against a :class:`~lead_s2r.scoring.run.SampleCache` that decoded them for an earlier scoring (the quickstart's).

Run: ``.venv/bin/python benchmarks/score_select.py [--rounds 3]``. The quickstart's synthetic NAVSIM data (32
trainval and 20 test logs, a third with pedestrians ahead) is generated and converted into a temporary folder; the
samples are decoded with PDMS's fields, the quickstart's split (test) and tag (scene_filter:pedestrians_ahead).
"""

import argparse
import tempfile
import time
from functools import partial
from pathlib import Path

from cpu_time import timed
from rich.console import Console

from lead_s2r.demo.quickstart import prepare
from lead_s2r.demo.table4 import EVAL_SPLITS, PERCEPTION_TAGS
from lead_s2r.scoring.run import SampleCache, choose_samples, make_scorer
from lead_s2r.shards import read_samples


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    split, tag = EVAL_SPLITS["navsim"], PERCEPTION_TAGS["navsim"]
    fields = make_scorer("pdms@navsim-1.1").fields
    with tempfile.TemporaryDirectory() as tmp:
        prepare("navsim", Path(tmp), 2, Console(quiet=True), time.perf_counter())  # as the quickstart
        data = Path(tmp) / "data" / "navsim"
        for round_ in range(args.rounds):
            baseline, decode_all = timed(
                lambda: [s for s in read_samples(data, fields=fields) if s["meta"]["split"] == split]
            )
            chosen, manifest_first = timed(lambda: choose_samples([data], fields, split)[0])
            tagged, with_tag = timed(lambda: choose_samples([data], fields, split, tag=tag)[0])
            cache = SampleCache()
            choose_samples([data], fields, split, cache=cache)
            (again, _), cached = timed(partial(choose_samples, [data], fields, split, cache=cache))
            assert [s["__key__"] for s in chosen] == [s["__key__"] for s in baseline] == [s["__key__"] for s in again]
            print(
                f"round {round_}: decode all, keep {split}: {len(baseline)} samples {decode_all:.2f} s; manifest "
                f"first: {manifest_first:.2f} s ({decode_all / manifest_first:.1f}x); {split} + {tag}: "
                f"{len(tagged)} samples {with_tag:.2f} s; {split} again from a SampleCache: {cached * 1e3:.2f} ms"
            )


if __name__ == "__main__":
    main()
