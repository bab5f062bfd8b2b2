"""NAVSIM submissions: the pickle loads where NAVSIM and nuPlan live (stand-ins at their module paths, in a
subprocess), names exactly their classes without them, covers multi-seed v1.1 and v2 two-stage, and refuses
(writing nothing) a missing token, a NaN pose, a short horizon and missing metadata."""

import importlib.util
import json
import pickle
import pickletools
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from lead_s2r.cli import main as cli_main
from lead_s2r.convert import convert
from lead_s2r.predictions import Prediction, write_predictions
from lead_s2r.shards import load_info, read_samples
from lead_s2r.submit import navsim as navsim_submit
from lead_s2r.submit.common import SubmissionError
from lead_s2r.synthetic import navsim as synth
from lead_s2r.synthetic import navsim_navhard as hard
from lead_s2r_adapters.navsim import NavsimAdapter

METADATA = navsim_submit.NavsimMetadata(
    "Team <a href='https://x.org/r.pdf'>X</a>", "A. B, C. D", "a@b.org", "Uni", "Germany"
)
GRID = 0.5 * np.arange(1, 9)

STAND_INS = {
    "nuplan/planning/simulation/trajectory/trajectory_sampling.py": """
        from dataclasses import dataclass

        @dataclass
        class TrajectorySampling:
            num_poses: int = None
            time_horizon: float = None
            interval_length: float = None
    """,
    "navsim/common/dataclasses.py": """
        from dataclasses import dataclass
        import numpy as np
        from nuplan.planning.simulation.trajectory.trajectory_sampling import TrajectorySampling

        @dataclass
        class Trajectory:
            poses: np.ndarray
            trajectory_sampling: TrajectorySampling
    """,
}
LOADER = """
import json, pickle, sys
with open(sys.argv[1], "rb") as file:
    submission = pickle.load(file)
out = {"keys": sorted(submission), "meta": {k: v for k, v in submission.items() if isinstance(v, str)}, "lists": {}}
for name, seeds in submission.items():
    if isinstance(seeds, list):
        out["lists"][name] = [
            {token: {"class": type(t).__module__ + "." + type(t).__name__,
                     "sampling": type(t.trajectory_sampling).__module__ + "." + type(t.trajectory_sampling).__name__,
                     "num_poses": t.trajectory_sampling.num_poses, "horizon": t.trajectory_sampling.time_horizon,
                     "interval": t.trajectory_sampling.interval_length,
                     "dtype": str(t.poses.dtype), "poses": t.poses.tolist()} for token, t in seed.items()}
            for seed in seeds
        ]
print(json.dumps(out))
"""


def load_on_server(path: Path, tmp_path: Path) -> dict:
    """Unpickle ``path`` in a fresh interpreter where the stand-ins are importable at the official paths."""
    root = tmp_path / "server_site"
    for relative, source in STAND_INS.items():
        file = root / relative
        file.parent.mkdir(parents=True, exist_ok=True)
        for package in [*file.relative_to(root).parents][:-1]:
            (root / package / "__init__.py").touch()
        file.write_text(textwrap.dedent(source))
    env = {"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"}
    result = subprocess.run(
        [sys.executable, "-c", LOADER, str(path)], capture_output=True, text=True, env=env, check=False
    )
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def stream_globals(data: bytes) -> set[str]:
    """``module.name`` of every STACK_GLOBAL in a protocol-4 pickle, read from the opcodes (nothing imported)."""
    memo: dict[int, object] = {}
    recent: list[object] = []
    found = set()
    for op, arg, _ in pickletools.genops(data):
        if op.name in ("SHORT_BINUNICODE", "BINUNICODE"):
            recent.append(arg)
        elif op.name in ("BINGET", "LONG_BINGET"):
            recent.append(memo.get(arg))
        elif op.name == "MEMOIZE":
            memo[len(memo)] = recent[-1] if recent else None
        elif op.name == "STACK_GLOBAL":
            found.add(f"{recent[-2]}.{recent[-1]}")
            recent.append(None)
        else:
            recent.append(None)
    return found


def predictions_file(path: Path, keys: list[str], t: np.ndarray, x_speed: float = 5.0, drop: int = 0) -> Path:
    """x = speed * t, y = 0.1 t^2, yaw = 0.02 t for every key but the first ``drop``."""
    rows = [Prediction(key, "navsim", t, np.column_stack([x_speed * t, 0.1 * t**2]), 0.02 * t) for key in keys[drop:]]
    return write_predictions(path, rows)


def expected_poses(x_speed: float = 5.0) -> np.ndarray:
    return np.column_stack([x_speed * GRID, 0.1 * GRID**2, 0.02 * GRID]).astype(np.float32)


@pytest.fixture(scope="module")
def navtest(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    """A converted v1 split and its token -> sample key."""
    raw, out = tmp_path_factory.mktemp("navsim_raw"), tmp_path_factory.mktemp("navsim_conv")
    synth.generate(raw, count=1)
    assert convert(NavsimAdapter(split="mini"), raw, out, progress=False).ok
    return out, {s["meta"]["extras"]["navsim"]["scene_token"]: s["__key__"] for s in read_samples(out, ("meta",))}


@pytest.fixture(scope="module")
def navhard(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    raw, out = tmp_path_factory.mktemp("navhard_raw"), tmp_path_factory.mktemp("navhard_conv")
    hard.generate(raw, count=1)
    adapter = NavsimAdapter(
        split=hard.SPLIT,
        scene_filter=str(raw / "scene_filters" / f"{hard.SPLIT}.yaml"),
        two_stage_mapping=str(raw / "train_test_split" / f"{hard.SPLIT}.yaml"),
    )
    assert convert(adapter, raw, out, progress=False).ok
    return out, {s["meta"]["extras"]["navsim"]["scene_token"]: s["__key__"] for s in read_samples(out, ("meta",))}


def metadata_args(**override: str) -> list[str]:
    values = {"team": METADATA.team_name, "authors": METADATA.authors, "email": METADATA.email}
    values |= {"institution": METADATA.institution, "country": METADATA.country} | override
    return [arg for name, value in values.items() for arg in (f"--{name}", value)]


def test_multi_seed_v11_loads_on_the_server_with_resampled_poses(navtest, tmp_path: Path, capsys) -> None:
    data, tokens = navtest
    keys = sorted(tokens.values())
    seed0 = predictions_file(tmp_path / "seed0.parquet", keys, GRID)  # on the grid
    seed1 = predictions_file(tmp_path / "seed1.parquet", keys, 0.25 * np.arange(1, 21), x_speed=4.0)  # 4 Hz, 5 s
    seed2 = predictions_file(tmp_path / "seed2.parquet", keys, np.arange(1.0, 5.0))  # 1 Hz: interpolated
    out = tmp_path / "submission.pkl"
    argv = ["submit", "navsim", "--data", str(data), "--out", str(out), *metadata_args()]
    assert cli_main([*argv, "--predictions", str(seed0), "--predictions", str(seed1), "--predictions", str(seed2)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["lists"] == {"predictions": {"seeds": 3, "tokens": len(tokens)}}

    loaded = load_on_server(out, tmp_path)
    assert loaded["keys"] == sorted(["team_name", "authors", "email", "institution", "country / region", "predictions"])
    assert loaded["meta"]["country / region"] == "Germany" and loaded["meta"]["team_name"] == METADATA.team_name
    seeds = loaded["lists"]["predictions"]
    assert len(seeds) == 3 and all(set(seed) == set(tokens) for seed in seeds)
    entry = seeds[0][next(iter(tokens))]
    assert entry["class"] == "navsim.common.dataclasses.Trajectory"
    assert entry["sampling"] == "nuplan.planning.simulation.trajectory.trajectory_sampling.TrajectorySampling"
    assert (entry["num_poses"], entry["horizon"], entry["interval"], entry["dtype"]) == (8, 4.0, 0.5, "float32")
    np.testing.assert_array_equal(np.float32(entry["poses"]), expected_poses())
    np.testing.assert_array_equal(np.float32(seeds[1][next(iter(tokens))]["poses"]), expected_poses(4.0))
    # 1 Hz knots (origin, 1, 2, 3, 4 s): half-second poses are midpoints, e.g. y(0.5) = (0 + 0.1) / 2
    interpolated = np.float32(seeds[2][next(iter(tokens))]["poses"])
    np.testing.assert_allclose(interpolated[:, 1], [0.05, 0.1, 0.25, 0.4, 0.65, 0.9, 1.25, 1.6], rtol=1e-6)
    np.testing.assert_allclose(interpolated[:, 0], 5 * GRID, rtol=1e-6)


def test_pickle_names_exactly_navsim_nuplan_and_numpy1_classes_and_needs_them(navtest, tmp_path: Path) -> None:
    data, tokens = navtest
    predictions = predictions_file(tmp_path / "p.parquet", sorted(tokens.values()), GRID)
    out = tmp_path / "submission.pkl"
    navsim_submit.write_navsim(out, METADATA, [predictions], [data])
    assert importlib.util.find_spec("navsim") is None and importlib.util.find_spec("nuplan") is None
    assert stream_globals(out.read_bytes()) == {
        "navsim.common.dataclasses.Trajectory",
        "nuplan.planning.simulation.trajectory.trajectory_sampling.TrajectorySampling",
        "numpy.core.multiarray._reconstruct",  # numpy 1.x's path: the server pins numpy 1.23.4
        "numpy.ndarray",
        "numpy.dtype",
    }
    with pytest.raises(ModuleNotFoundError, match="navsim"):
        pickle.loads(out.read_bytes())


def test_two_stage_lists_follow_the_converted_navhard_split(navhard, tmp_path: Path) -> None:
    data, tokens = navhard
    info = load_info(data)["two_stage"]
    predictions = predictions_file(tmp_path / "p.parquet", sorted(tokens.values()), GRID)
    out = tmp_path / "submission.pkl"
    report = navsim_submit.write_navsim(out, METADATA, [predictions], [data], two_stage=True)
    assert report["format"] == "navsim-v2 two-stage"
    loaded = load_on_server(out, tmp_path)
    assert "predictions" not in loaded["keys"]
    first, second = loaded["lists"]["first_stage_predictions"], loaded["lists"]["second_stage_predictions"]
    assert len(first) == len(second) == 1
    assert set(first[0]) == set(info["stage_one_tokens"]) and len(first[0]) == 2
    assert set(second[0]) == set(info["stage_two_tokens"]) and len(second[0]) == 6
    assert all(len(token) == 17 for token in second[0])
    np.testing.assert_array_equal(np.float32(second[0][info["stage_two_tokens"][0]]["poses"]), expected_poses())
    with pytest.raises(SubmissionError, match="--two-stage with 2 --predictions files; NAVSIM v2 scores exactly one"):
        navsim_submit.write_navsim(tmp_path / "v2.pkl", METADATA, [predictions, predictions], [data], two_stage=True)
    with pytest.raises(SubmissionError, match=r"synthetic.*--two-stage"):
        navsim_submit.write_navsim(tmp_path / "v1.pkl", METADATA, [predictions], [data])


def test_check_reports_a_written_file_and_rejects_a_foreign_pickle(navtest, tmp_path: Path, capsys) -> None:
    data, tokens = navtest
    predictions = predictions_file(tmp_path / "p.parquet", sorted(tokens.values()), GRID)
    out = tmp_path / "submission.pkl"
    navsim_submit.write_navsim(out, METADATA, [predictions, predictions], [data])
    assert cli_main(["submit", "--check", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["lists"]["predictions"] == {"seeds": 2, "tokens": len(tokens)}
    assert report["metadata"]["country / region"] == "Germany"
    bad = tmp_path / "bad.pkl"
    bad.write_bytes(pickle.dumps({"team_name": "x"}))
    with pytest.raises(SubmissionError, match=r"bad.pkl: prediction lists \[\]: expected 'predictions'"):
        navsim_submit.check_navsim(bad)


def refused(call, out: Path, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()
    assert not out.exists() and not list(out.parent.glob("*.partial"))


def test_missing_token_nan_pose_short_horizon_and_missing_metadata_write_nothing(navtest, tmp_path: Path) -> None:
    data, tokens = navtest
    keys = sorted(tokens.values())
    out = tmp_path / "submission.pkl"
    missing = predictions_file(tmp_path / "missing.parquet", keys, GRID, drop=1)
    lost = next(token for token, key in tokens.items() if key == keys[0])
    refused(
        lambda: navsim_submit.write_navsim(out, METADATA, [missing], [data]), out, f"1 of {len(keys)} tokens .*{lost}"
    )

    nan = [Prediction(key, "navsim", GRID, np.column_stack([GRID, GRID]), np.full(8, np.nan)) for key in keys]
    path = write_predictions(tmp_path / "nan.parquet", nan)
    refused(lambda: navsim_submit.write_navsim(out, METADATA, [path], [data]), out, "yaw is NaN")

    short = predictions_file(tmp_path / "short.parquet", keys, GRID[:6])  # 6 poses: 3 s
    refused(
        lambda: navsim_submit.write_navsim(out, METADATA, [short], [data]),
        out,
        "ends at 3 s, NAVSIM needs 8 poses up to 4 s",
    )

    full = predictions_file(tmp_path / "full.parquet", keys, GRID)
    refused(
        lambda: navsim_submit.write_navsim(out, METADATA, [full], [tmp_path / "nope"]),
        out,
        "nope: no such converted folder",
    )
    argv = ["--debug", "submit", "navsim", "--data", str(data), "--out", str(out), "--predictions", str(full)]
    refused(lambda: cli_main([*argv, *metadata_args(country=" ")]), out, "'country' .*--country")


def test_validate_rejects_what_the_server_would(navtest) -> None:
    _, tokens = navtest
    good = {token: np.zeros((8, 3), np.float32) for token in tokens}
    base = {**METADATA.as_keys(), "predictions": [good]}
    navsim_submit.validate(base, {"predictions": sorted(tokens)})
    token = next(iter(tokens))
    cases = {
        "float32 \\(8, 3\\) at 0.5 s, got float32 \\(6, 3\\)": {**good, token: np.zeros((6, 3), np.float32)},
        "float32 \\(8, 3\\) at 0.5 s, got float64": {**good, token: np.zeros((8, 3))},
        "NaN or inf": {**good, token: np.full((8, 3), np.nan, np.float32)},
    }
    for message, seed in cases.items():
        with pytest.raises(SubmissionError, match=message):
            navsim_submit.validate({**base, "predictions": [good, seed]}, {"predictions": sorted(tokens)})
    renamed = {("country/region" if k == "country / region" else k): v for k, v in base.items()}
    with pytest.raises(SubmissionError, match=r"\['country/region'\] unexpected, \['country / region'\] missing"):
        navsim_submit.validate(renamed)
    with pytest.raises(SubmissionError, match="'email' is missing"):
        navsim_submit.NavsimMetadata("t", "a", "", "i", "c")
