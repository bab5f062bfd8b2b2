"""WOD-E2E submissions: shards parse with our descriptors and with a hand-written wire decoder, frame names are the
synthetic records' own, the tar.gz holds exactly the shards, and bad input is refused with nothing written."""

import json
import struct
import tarfile
from pathlib import Path

import numpy as np
import pytest

from lead_s2r.cli import main as cli_main
from lead_s2r.convert import convert
from lead_s2r.predictions import Prediction, most_probable, write_predictions
from lead_s2r.shards import read_samples
from lead_s2r.submit import wod_e2e as wod_submit
from lead_s2r.submit.common import SubmissionError
from lead_s2r.synthetic import wod_e2e as synth
from lead_s2r_adapters.wod_e2e import WodE2EAdapter

METADATA = wod_submit.WodMetadata(
    account_name="someone@uni.org",
    unique_method_name="LTFv6-s2r",
    authors=["A. B", "C. D"],
    num_model_parameters="60M",
    uses_public_model_pretraining=False,
    affiliation="Uni",
)
GRID_2HZ = 0.5 * np.arange(1, 11)


def varint(data: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[at]
        value |= (byte & 0x7F) << shift
        at, shift = at + 1, shift + 7
        if byte < 0x80:
            return value, at


def wire_fields(data: bytes) -> list[tuple[int, int | bytes]]:
    """(field number, value) pairs of a protobuf message: varints as int, length-delimited as bytes."""
    out, at = [], 0
    while at < len(data):
        key, at = varint(data, at)
        number, kind = key >> 3, key & 7
        if kind == 0:
            value, at = varint(data, at)
        elif kind == 2:
            length, at = varint(data, at)
            value, at = data[at : at + length], at + length
        else:
            raise AssertionError(f"unexpected wire type {kind} for field {number}")
        out.append((number, value))
    return out


def decode_submission(data: bytes) -> dict:
    """Waymo's field numbers, read independently of our descriptors."""
    fields = wire_fields(data)
    frames = {}
    for number, value in fields:
        if number == 1:
            entry = dict(wire_fields(value))
            trajectory = dict(wire_fields(entry[2]))
            x, y = (np.array(struct.unpack(f"<{len(trajectory[n]) // 4}f", trajectory[n])) for n in (1, 2))
            frames[entry[1].decode()] = np.column_stack([x, y])
    scalars = {number: value for number, value in fields if number != 1}
    authors = [value.decode() for number, value in fields if number == 5]
    return {"frames": frames, "fields": scalars, "authors": authors}


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    """A converted WOD-E2E folder (1 segment per split) and the test split's sample key -> frame name."""
    raw, out = tmp_path_factory.mktemp("wod_raw"), tmp_path_factory.mktemp("wod_conv")
    synth.generate(raw, count=1, seed=3)
    assert convert(WodE2EAdapter(), raw, out, progress=False).ok
    metas = {s["__key__"]: s["meta"] for s in read_samples(out, ("meta",))}
    return out, {key: m["extras"]["wod_e2e"]["frame_name"] for key, m in metas.items() if m["split"] == "test"}


def two_inference_predictions(path: Path, keys: list[str], t: np.ndarray = GRID_2HZ) -> Path:
    """Per key: inference 0 (p 0.3) drives x = 5 t; inference 1 (p 0.7) drives x = 3 t, y = 0.2 t."""
    rows = []
    for key in keys:
        rows.append(Prediction(key, "wod_e2e", t, np.column_stack([5 * t, 0 * t]), np.full(len(t), np.nan), 0.3, 0))
        rows.append(Prediction(key, "wod_e2e", t, np.column_stack([3 * t, 0.2 * t]), np.full(len(t), np.nan), 0.7, 1))
    return write_predictions(path, rows)


def test_shards_tar_and_frames_as_the_server_reads_them(converted, tmp_path: Path, capsys) -> None:
    data, frames = converted
    predictions = two_inference_predictions(tmp_path / "p.parquet", sorted(frames))
    out = tmp_path / "MySubmission"
    argv = ["submit", "wod-e2e", "--predictions", str(predictions), "--data", str(data), "--out", str(out)]
    argv += ["--account", "someone@uni.org", "--method", "LTFv6-s2r", "--authors", "A. B", "C. D"]
    assert cli_main([*argv, "--num-params", "60M", "--pretrained", "false", "--shards", "3"]) == 0
    report = json.loads(capsys.readouterr().out)
    names = [f"submission.binproto-{i:05d}-of-00003" for i in range(3)]
    assert sorted(p.name for p in out.iterdir()) == names
    assert list(report["shards"]) == names and sum(report["shards"].values()) == len(frames) == report["frames"]

    with tarfile.open(tmp_path / "MySubmission.tar.gz", "r:gz") as tar:
        members = tar.getmembers()
        assert [m.name for m in members if m.isdir()] == ["MySubmission"]
        assert sorted(m.name for m in members if m.isfile()) == [f"MySubmission/{n}" for n in names]
        assert all(tar.extractfile(f"MySubmission/{n}").read() == (out / n).read_bytes() for n in names)

    synthetic_names = {f.name for f in synth.make_dataset(1, seed=3).frames if f.split == "test"}
    decoded = [decode_submission((out / name).read_bytes()) for name in names]
    written = {name: xy for shard in decoded for name, xy in shard["frames"].items()}
    assert set(written) == synthetic_names == set(frames.values())
    assert [len(shard["frames"]) for shard in decoded] == [4, 4, 3]  # ceil(11 / 3) per shard, as the tutorial
    t = 0.25 * np.arange(1, 21)
    for xy in written.values():  # the p = 0.7 inference, 2 Hz -> 4 Hz (linear, so exact)
        np.testing.assert_allclose(xy, np.column_stack([3 * t, 0.2 * t]), rtol=1e-6)
    for shard in decoded:  # every shard repeats the metadata, with Waymo's field numbers
        fields = shard["fields"]
        assert fields[2] == 1 and fields[3] == b"someone@uni.org" and fields[4] == b"LTFv6-s2r"
        assert fields[11] == 0 and fields[12] == b"60M" and shard["authors"] == ["A. B", "C. D"]

    parsed = wod_submit.read_shards(tmp_path / "MySubmission.tar.gz")
    message = wod_submit.E2EDChallengeSubmission.FromString(parsed[names[0]])
    assert message.predictions[0].frame_name in synthetic_names and len(message.predictions[0].trajectory.pos_x) == 20


def test_check_reads_a_folder_and_rejects_tutorial_part_names(converted, tmp_path: Path, capsys) -> None:
    data, frames = converted
    predictions = two_inference_predictions(tmp_path / "p.parquet", sorted(frames))
    out = tmp_path / "sub"
    wod_submit.write_wod(out, METADATA, predictions, [data])
    assert cli_main(["submit", "--check", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["frames"] == len(frames) and report["metadata"]["num_model_parameters"] == "60M"
    with pytest.raises(SubmissionError, match=r"nope\.tar\.gz: no such submission file"):
        cli_main(["submit", "--check", str(tmp_path / "nope.tar.gz"), "--debug"])  # --debug: raise, not print
    (out / "submission.binproto-00000-of-00001").rename(out / "part0")
    with pytest.raises(SubmissionError, match=r"part0 are not <stem>\.binproto-00000-of-0000N"):
        wod_submit.check_wod(out)


def refused(call, out: Path, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()
    assert not out.exists() and not wod_submit.tar_path(out).exists() and not list(out.parent.glob("*.partial"))


def test_missing_frame_short_horizon_and_bad_metadata_write_nothing(converted, tmp_path: Path) -> None:
    data, frames = converted
    keys = sorted(frames)
    out = tmp_path / "sub"
    missing = two_inference_predictions(tmp_path / "missing.parquet", keys[1:])
    refused(lambda: wod_submit.write_wod(out, METADATA, missing, [data]), out, f"1 of 11 frames .*{frames[keys[0]]}")
    short = two_inference_predictions(tmp_path / "short.parquet", keys, 0.25 * np.arange(1, 17))  # 16 points: 4 s
    refused(
        lambda: wod_submit.write_wod(out, METADATA, short, [data]),
        out,
        "short.parquet: .*horizon 4 s ends before .* 5 s",
    )
    good = two_inference_predictions(tmp_path / "good.parquet", keys)
    argv = ["--debug", "submit", "wod-e2e", "--predictions", str(good), "--data", str(data), "--out", str(out)]
    argv += ["--account", "someone@uni.org", "--method", "m", "--authors", "A", "--pretrained", "true"]
    refused(lambda: cli_main([*argv, "--num-params", "60M"]), out, "'public_model_names' is empty")
    refused(lambda: cli_main([*argv, "--num-params", "", "--public-models", "Qwen2-VL"]), out, "'num_model_parameters'")
    with pytest.raises(SubmissionError, match=r"'num_model_parameters' is '1\.5B'; write an integer"):
        wod_submit.WodMetadata("a@b.c", "m", ["A"], "1.5B", False)
    with pytest.raises(SubmissionError, match="'uses_public_model_pretraining' is required"):
        wod_submit.WodMetadata("a@b.c", "m", ["A"], "60M", None)


def test_validate_rejects_wrong_point_counts_nan_and_duplicates() -> None:
    def shard(points: list[np.ndarray]) -> object:
        message = METADATA.message()
        for i, xy in enumerate(points):
            entry = message.predictions.add(frame_name=f"seq-{i:03d}")
            entry.trajectory.pos_x.extend(xy[:, 0].tolist())
            entry.trajectory.pos_y.extend(xy[:, 1].tolist())
        return message

    good = np.zeros((20, 2))
    assert wod_submit.validate({"s.binproto-00000-of-00001": shard([good, good])}, ["seq-000", "seq-001"]) == 2
    cases = {
        "frame 'seq-001' has 19 x / 19 y points, not 20": [good, good[:19]],
        "frame 'seq-000': trajectory holds NaN": [np.full((20, 2), np.nan)],
    }
    for message, points in cases.items():
        with pytest.raises(SubmissionError, match=message):
            wod_submit.validate({"s.binproto-00000-of-00001": shard(points)})
    with pytest.raises(SubmissionError, match="'seq-000' appears twice"):
        wod_submit.validate({"s.binproto-00000-of-00002": shard([good]), "s.binproto-00001-of-00002": shard([good])})
    with pytest.raises(SubmissionError, match="not one complete set"):
        wod_submit.validate({"s.binproto-00001-of-00002": shard([good])})


def test_one_trajectory_per_frame_is_the_most_probable_lowest_inference_on_ties() -> None:
    """The rule every reader of several inferences uses (leaderboards, PDMS/EPDMS, the report's drawings)."""
    t = 0.5 * np.arange(1, 9)
    xy = np.zeros((8, 2))
    made = [Prediction("k", "wod_e2e", t, xy, 0 * t, probability, inference) for inference, probability in
            enumerate((0.2, 0.4, 0.4))]  # fmt: skip
    for order in (made, made[::-1]):
        assert most_probable(order).inference == 1
