"""Damaged 123D logs and maps, one test per kind the fuzz (tests/test_fuzz.py) found: each was a crash of the
process, a traceback or a log that vanished, and each is now one errors.jsonl line naming the file and field.

Every damage is made here from a log py123d's own writer wrote, with pyarrow (a table re-written with one value,
column or metadata entry changed) or by patching the file's bytes where pyarrow cannot write the damage.
"""

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import shapely
from corruptions import aborting_laz, hardlink_copy

pytest.importorskip("py123d", reason="py123d is installed with --no-deps in CI (docs/datasets/py123d.md)")
import msgpack

from lead_s2r.convert import convert
from lead_s2r.synthetic import py123d as synth
from lead_s2r_adapters.py123d import Py123dAdapter
from lead_s2r_adapters.py123d_arrow import Py123dFormatError, decode_points

LOG = Path("logs") / "nuplan_test" / "log-left"
MAP = Path("maps") / "nuplan" / "nuplan_synthetic-log-left.arrow"
LIGHTS = LOG / "traffic_light_detections.arrow"
EGO = LOG / "ego_state_se3.arrow"
SYNC = LOG / "sync.arrow"


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One log of 43 iterations (3 samples) and its map, never written by a test."""
    root = tmp_path_factory.mktemp("py123d")
    synth.write_log(root, "log-left", index=0, frames=6)
    return root


def read(path: Path) -> pa.Table:
    with pa.memory_map(str(path)) as source:
        return pa.ipc.open_file(source).read_all()


def write(path: Path, table: pa.Table) -> None:
    """Replace a hard-linked file by ``table`` written as an Arrow IPC file."""
    path.unlink()
    with pa.OSFile(str(path), "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
        writer.write_table(table)


def patch_bytes(path: Path, change: Callable[[bytes], bytes]) -> None:
    data = path.read_bytes()
    path.unlink()
    path.write_bytes(change(data))


def set_column(path: Path, name: str, values: pa.Array | list) -> None:
    table = read(path)
    write(path, table.set_column(table.column_names.index(name), name, values))


def set_metadata(path: Path, entry: str, value: object) -> None:
    """One entry of the file's msgpack schema metadata replaced by ``value``."""
    table = read(path)
    meta = msgpack.unpackb(table.schema.metadata[b"metadata"], strict_map_key=False)
    meta[entry] = value
    write(path, table.replace_schema_metadata({b"metadata": msgpack.packb(meta)}))


def convert_error(src: Path, out: Path) -> str:
    """The one error line of converting ``src``, whose one log is damaged."""
    result = convert(Py123dAdapter(), src, out)
    assert result.samples == 0 and len(result.errors) == 1, result.errors
    (line,) = (out / "errors.jsonl").read_text().splitlines()
    return json.loads(line)["error"]


def offsets_past_values(src: Path) -> None:
    """The lane ids' last list offset (the file's first run of int32 0..43) moved far past the values: pyarrow writes
    no such file, and read it aborted or segfaulted the process."""
    run = np.arange(44, dtype="<i4").tobytes()
    at = (src / LIGHTS).read_bytes().index(run) + 43 * 4
    patch_bytes(src / LIGHTS, lambda d: d[:at] + np.int32(2_000_000_000).tobytes() + d[at + 4 :])


def ego_row(src: Path, row: int, values: list[float]) -> None:
    table = read(src / EGO)
    poses = table["ego_state_se3.imu_se3"].to_pylist()
    poses[row] = values
    set_column(src / EGO, "ego_state_se3.imu_se3", pa.array(poses, table.schema.field(1).type))


def box_row(src: Path, box: list[float]) -> None:
    """The first box of the first row replaced by ``box``."""
    path, name = src / LOG / "box_detections_se3.arrow", "box_detections_se3.bounding_box_se3"
    values = read(path)[name]
    rows = values.to_pylist()
    rows[0][0] = box
    set_column(path, name, pa.array(rows, values.type))


def sync_row(src: Path, column: str, row: int, value: int) -> None:
    rows = read(src / SYNC)[column].to_pylist()
    rows[row] = value
    set_column(src / SYNC, column, pa.array(rows, pa.int64()))


def swap_timestamps(src: Path) -> None:
    stamps = read(src / SYNC)["sync.timestamp_us"].to_pylist()
    stamps[4], stamps[5] = stamps[5], stamps[4]
    set_column(src / SYNC, "sync.timestamp_us", pa.array(stamps, pa.int64()))


def null_in_list(src: Path, path: Path, name: str) -> None:
    values = read(src / path)[name]
    rows = values.to_pylist()
    rows[0] = [None, *rows[0][1:]]
    set_column(src / path, name, pa.array(rows, values.type))


def map_object_field(src: Path, object_id: int, field: str, value: object) -> None:
    """One field of a map object's msgpack replaced by ``value`` (``...``: deleted)."""
    table = read(src / MAP)
    features = table["features"].to_pylist()
    at = table["object_id"].to_pylist().index(object_id)
    fields = msgpack.unpackb(features[at], strict_map_key=False)
    if value is ...:
        del fields[field]
    else:
        fields[field] = value
    features[at] = msgpack.packb(fields)
    set_column(src / MAP, "features", pa.array(features, pa.binary()))


def last_replaced(data: bytes, old: bytes, new: bytes) -> bytes:
    """``data`` with the last occurrence of ``old`` (in the file's footer schema, which the reader reads) replaced."""
    at = data.rindex(old)
    return data[:at] + new + data[at + len(old) :]


QUATERNION_ZERO = [10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
CASES: dict[str, tuple[Callable[[Path], None], Path, str]] = {
    "list offsets past the values": (
        offsets_past_values,
        LIGHTS,
        "Column 1: In chunk 0: Invalid: Length spanned by list offsets",
    ),
    "a column name not UTF-8": (
        lambda src: patch_bytes(
            src / LIGHTS, lambda d: last_replaced(d, b"light_detections.status", b"light\xffdetections.status")
        ),
        LIGHTS,
        "not a readable Arrow IPC file ('utf-8' codec can't decode",
    ),
    "an int type of 4 bits": (  # flatbuffer Int table: is_signed True, then bitWidth 64 ('@')
        lambda src: patch_bytes(src / SYNC, lambda d: last_replaced(d, b"\x01@\x00\x00\x00", b"\x01\x04\x00\x00\x00")),
        SYNC,
        "Integers with less than 8 bits not implemented",
    ),
    "sync.arrow deleted": (lambda src: (src / SYNC).unlink(), SYNC, "missing; copy or convert this log again"),
    "a modality file deleted": (
        lambda src: (src / LOG / "camera.pcam_f0.arrow").unlink(),
        LOG / "camera.pcam_f0.arrow",
        "missing (sync.arrow lists it)",
    ),
    "a sync row past the file": (
        lambda src: sync_row(src, "box_detections_se3", 2, 1_000_000),
        SYNC,
        "field 'box_detections_se3': row index 1000000 past the 43 rows of box_detections_se3.arrow",
    ),
    "a negative sync row": (
        lambda src: sync_row(src, "ego_state_se3", 2, -5),
        SYNC,
        "field 'ego_state_se3': negative row index -5",
    ),
    "timestamps of another type": (
        lambda src: set_column(src / SYNC, "sync.timestamp_us", pa.array([1.5] * 43)),
        SYNC,
        "field 'sync.timestamp_us': expected one integer per iteration, got double",
    ),
    "timestamps out of order": (swap_timestamps, SYNC, "timestamps do not increase at iteration 5"),
    "a NaN ego pose": (
        lambda src: ego_row(src, 3, [np.nan] * 7),
        EGO,
        "field 'ego_state_se3.imu_se3': row 3: the pose is null, not finite, 1e+08 m or more away or has a zero",
    ),
    "a zero quaternion": (lambda src: ego_row(src, 3, QUATERNION_ZERO), EGO, "row 3: the pose is null, not finite"),
    "an ego pose a flipped exponent away": (
        lambda src: ego_row(src, 3, [1e300, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]),
        EGO,
        "row 3: the pose is null, not finite, 1e+08 m or more away",
    ),
    "an ego pose 50 km from the one before": (
        lambda src: ego_row(src, 3, [5e4, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]),
        EGO,
        "row 3: the ego moved 4.99e+04 m since the iteration before, faster than 200 m/s",
    ),
    "a column of another type": (
        lambda src: set_column(src / EGO, "ego_state_se3.imu_se3", pa.array(["x"] * 43)),
        EGO,
        "field 'ego_state_se3.imu_se3': expected a list of numbers per row, got string",
    ),
    "a wrong-typed metadata pose": (
        lambda src: set_metadata(src / EGO, "rear_axle_to_imu_se3", "x"),
        EGO,
        "field 'metadata.rear_axle_to_imu_se3': expected 7 finite numbers",
    ),
    "a zero quaternion in a camera's extrinsic": (
        lambda src: set_metadata(src / LOG / "camera.pcam_f0.arrow", "camera_to_imu_se3", [1.0, 0, 0, 0, 0, 0, 0]),
        LOG / "camera.pcam_f0.arrow",
        "field 'metadata.camera_to_imu_se3': the rotation is a zero quaternion",
    ),
    "a wrong-typed vehicle size": (
        lambda src: set_metadata(src / EGO, "width", {"k": None}),
        EGO,
        "field 'metadata': ego metadata lacks the vehicle size",
    ),
    "a null inside a list of box labels": (
        lambda src: null_in_list(src, LOG / "box_detections_se3.arrow", "box_detections_se3.label"),
        LOG / "box_detections_se3.arrow",
        "row 0: a null inside a list of boxes",
    ),
    "a box 1e300 m away": (
        lambda src: box_row(src, [1e300, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 4.0, 2.0, 1.5]),
        LOG / "box_detections_se3.arrow",
        "row 0: a box value is not finite or 1e+08 or more, or a quaternion is zero",
    ),
    "a box with a zero quaternion": (
        lambda src: box_row(src, [5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 4.0, 2.0, 1.5]),
        LOG / "box_detections_se3.arrow",
        "row 0: a box value is not finite or 1e+08 or more, or a quaternion is zero",
    ),
    "a null lane id of a traffic light": (
        lambda src: null_in_list(src, LIGHTS, "traffic_light_detections.lane_id"),
        LIGHTS,
        "row 0: a null lane id or status",
    ),
    "a wrong-typed name of the log": (
        lambda src: set_metadata(src / SYNC, "log_name", [1, "a"]),
        SYNC,
        "field 'metadata.log_name': expected a string, got [1, 'a']",
    ),
    "a wrong-typed map entry of the log": (
        lambda src: set_metadata(src / SYNC, "map_metadata", True),
        SYNC,
        "field 'metadata.map_metadata': expected a map, got bool",
    ),
    "a wrong-typed route polyline": (
        lambda src: set_metadata(src / LOG / "route_position.arrow", "polyline_x", "x"),
        LOG / "route_position.arrow",
        "field 'metadata.polyline_x': expected N finite numbers",
    ),
    "a map lane's centreline a number": (
        lambda src: map_object_field(src, synth.LANES["approach"][0], "centerline", 7),
        MAP,
        "map object 1: a field is missing or of a wrong type (IndexError",
    ),
    "a map lane without its centreline": (
        lambda src: map_object_field(src, synth.LANES["approach"][0], "centerline", ...),
        MAP,
        "map object 1: a field is missing or of a wrong type (KeyError",
    ),
    "a map lane's group a word": (
        lambda src: map_object_field(src, synth.LANES["approach"][0], "lane_group_id", "x"),
        MAP,
        "map object 1: a field is missing or of a wrong type (ValueError",
    ),
    "a map lane's speed limit a list": (
        lambda src: map_object_field(src, synth.LANES["approach"][0], "speed_limit_mps", []),
        MAP,
        "map object 1: a field is missing or of a wrong type (TypeError",
    ),
    "a connector's predecessor past int64": (
        lambda src: map_object_field(src, synth.LANES["turn"][0], "predecessor_ids", [2**64 - 1]),
        MAP,
        "map object 2: a field is missing or of a wrong type (OverflowError",
    ),
    "a map geometry that is not WKB": (
        lambda src: set_column(src / MAP, "wkb", pa.array([b"\x01\x03garbage"] * read(src / MAP).num_rows)),
        MAP,
        "field 'wkb': not a WKB geometry",
    ),
    "a map point 1e300 m away": (
        lambda src: set_column(
            src / MAP, "wkb", pa.array([shapely.box(0, 0, 1e300, 1).wkb] * read(src / MAP).num_rows)
        ),
        MAP,
        "field 'wkb': map object 1: a point is not finite or 1e+08 m or more away",
    ),
    "a metadata pose 1e300 m away": (
        lambda src: set_metadata(src / EGO, "center_to_imu_se3", [1e300, 0, 0, 1, 0, 0, 0]),
        EGO,
        "field 'metadata.center_to_imu_se3': the position is 1e+08 m or more away",
    ),
    "map ids of another type": (
        lambda src: set_column(src / MAP, "object_id", pa.array(["x"] * read(src / MAP).num_rows)),
        MAP,
        "field 'object_id': expected an integer per map object, got string",
    ),
}


@pytest.mark.parametrize("case", CASES)
def test_a_damaged_file_is_one_error_line_naming_it(pristine: Path, tmp_path: Path, case: str) -> None:
    damage, damaged, message = CASES[case]
    src = tmp_path / "src"
    hardlink_copy(pristine, src)
    damage(src)
    error = convert_error(src, tmp_path / "out")
    assert error.startswith(f"Py123dFormatError: {src / damaged}") and message in error, error


def test_msgpack_metadata_that_is_not_a_map_or_not_msgpack(pristine: Path, tmp_path: Path) -> None:
    """Each error msgpack and py123d's array maps raise on a damaged blob is the file's format error."""
    no_data = {"width": {"__ndarray__": True, "dtype": "<f8", "shape": [1]}}  # an array map without its bytes
    cases = [
        (msgpack.packb([1, 2]), "expected a msgpack map, got list"),
        (b"\xc1", "not py123d msgpack (FormatError"),
        (msgpack.packb({(1, 2): 3}), "not py123d msgpack (TypeError: unhashable type: 'list'"),
        (msgpack.packb(no_data), "not py123d msgpack (KeyError"),
    ]
    for k, (blob, message) in enumerate(cases):
        src = tmp_path / f"src-{k}"
        hardlink_copy(pristine, src)
        write(src / EGO, read(src / EGO).replace_schema_metadata({b"metadata": blob}))
        error = convert_error(src, tmp_path / f"out-{k}")
        assert error.startswith(f"Py123dFormatError: {src / EGO}, field 'metadata': {message}"), error


def test_the_fuzz_wrong_type_rewrites_an_arrow_file_with_one_value_changed(pristine: Path, tmp_path: Path) -> None:
    """corruptions.corrupt's wrong_type on 123D files: the file stays readable Arrow and one value (a metadata entry,
    a map object's field or a column) differs, so a fuzz trial tests a reader, not the IPC framing."""
    from corruptions import corrupt

    rng = np.random.default_rng(0)
    for trial in range(6):
        for name in (EGO, MAP):
            path = tmp_path / f"{trial}-{name.name}"
            path.write_bytes((pristine / name).read_bytes())
            corrupt(path, "wrong_type", rng)
            before, after = read(pristine / name), read(path)
            assert after.num_rows == before.num_rows
            assert not after.equals(before, check_metadata=True)


def test_a_laz_payload_that_aborts_the_decoder_fails_its_log_only(tmp_path: Path) -> None:
    """A LAZ chunk table claiming 2**31 - 1 chunks makes lazrs abort its process (issue 26's LEAD files); 123D's
    LAZ payloads are decoded in the same helper process, so only the log is lost, with a line naming its file."""
    synth.write_log(tmp_path / "src", "log-left", index=0, frames=6, codec="laz")
    synth.write_log(tmp_path / "src", "log-good", index=1, frames=6, codec="laz")
    path = tmp_path / "src" / LOG / "lidar.lidar_top.arrow"
    blobs = read(path)["lidar.lidar_top.data"].to_pylist()
    set_column(path, "lidar.lidar_top.data", pa.array([blobs[0], aborting_laz(blobs[1]), *blobs[2:]], pa.binary()))
    result = convert(Py123dAdapter(), tmp_path / "src", tmp_path / "out")
    (error,) = result.errors
    assert error["log"] == "nuplan_test/log-left" and result.samples == 3  # log-good, whole
    assert error["error"].startswith(f"Py123dFormatError: {path}, field 'data': LiDAR payload is not valid LAZ")
    assert "the LAZ decoder died on it" in error["error"]


def ipc_stream(batch: pa.RecordBatch | None, schema: pa.Schema) -> bytes:
    """An Arrow IPC stream as py123d's ipc codec writes a LiDAR payload (``batch`` None: the schema alone)."""
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, schema) as writer:
        if batch is not None:
            writer.write_batch(batch)
    return sink.getvalue().to_pybytes()


def test_a_damaged_ipc_lidar_payload_is_refused(tmp_path: Path) -> None:
    xyz = {axis: pa.array([1.0, 2.0]) for axis in "xyz"}
    not_utf8 = pa.array([b"\xff", b"a"], pa.binary()).view(pa.string())  # pyarrow writes it unchecked
    bad = pa.RecordBatch.from_pydict({**xyz, "label": not_utf8})
    words = pa.RecordBatch.from_pydict({**xyz, "label": pa.array(["car", "bus"])})
    cases = [
        (ipc_stream(bad, bad.schema), "Invalid UTF8"),
        (ipc_stream(None, words.schema), "not an Arrow stream (StopIteration"),
        (ipc_stream(words, words.schema), "column 'label' is string, not numbers"),
    ]
    for blob, message in cases:
        with pytest.raises(
            Py123dFormatError, match=rf"^{tmp_path}, field 'data': LiDAR payload .*{re.escape(message)}"
        ):
            decode_points(blob, tmp_path)
    good = pa.RecordBatch.from_pydict(xyz)
    points, features = decode_points(ipc_stream(good, good.schema), tmp_path)
    assert points.tolist() == [[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]] and features == {}
