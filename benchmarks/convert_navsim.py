"""NAVSIM conversion throughput: scenes per second for one worker, with and without maps.

.venv/bin/python benchmarks/convert_navsim.py --logs 6
"""

import argparse
import tempfile
from pathlib import Path

from cpu_time import timed

from lead_s2r.convert import convert
from lead_s2r.synthetic import navsim
from lead_s2r_adapters import navsim_map
from lead_s2r_adapters.navsim import NavsimAdapter


def run(src: Path, out: Path, maps: Path | None) -> tuple[int, float]:
    navsim_map.load_map.cache_clear()  # count the one map load per location in the timing
    adapter = NavsimAdapter(split=navsim.DATA_SPLIT, maps=str(maps) if maps else None)
    result, elapsed = timed(lambda: convert(adapter, src, out, workers=1, force=True))
    if not result.ok:
        raise SystemExit(f"conversion failed: {result.errors}")
    return result.samples, elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", type=int, default=6, help="synthetic logs of 20 frames (7 scenes each)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "raw"
        navsim.generate(src, count=args.logs)
        for label, maps in (("without maps", None), ("with maps", src / "maps")):
            scenes, seconds = run(src, Path(tmp) / label.replace(" ", "_"), maps)
            print(f"{label:13s} {scenes:4d} scenes in {seconds:6.2f} s = {scenes / seconds:7.1f} scenes/s per worker")


if __name__ == "__main__":
    main()
