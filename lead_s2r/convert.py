"""Conversion driver: raw logs -> validated schema v1 samples in webdataset shards, resumable, fault-isolated and
deterministic.

The same raw data and options give the same bytes in every file of the folder, whatever the number of workers: seeded
training draws shards by name, so shards whose contents hung on which worker finished first would make two identical
runs train on different data. Each log is one job of an executor (:mod:`lead_s2r.processes`: local processes, or Ray
tasks on a cluster whose nodes all see ``out``), converted in any order, so a long log holds up no other; a job writes
its log to a fragment of its own (``shards/log-<position>.<run>.partial``: its tar members, no end-of-archive blocks;
``<run>`` is new for every call). The driver appends the fragments to shards in the order of the log list, skipping
failed and skipped logs, and closes a shard at the first log boundary after ``shard_size`` samples: a log never
straddles two shards, and names and contents are those one process converting the logs in turn writes. Appending is
``copy_file_range`` in the kernel (45 MB, 1000 CARLA samples, in 15 ms). A slow log holds back assembly, not conversion:
the logs after it wait on disk as fragments. A job run again (Ray retries a job whose worker or node died) truncates its
fragment first, so no partial fragment of the lost attempt remains.

A closed shard is fsynced and renamed from ``.partial`` before the driver records it (with its logs and manifest rows)
in ``progress.jsonl``; a fragment is deleted once appended. After a kill, a rerun deletes fragments, partial and
unrecorded shards (when it starts and again when it ends) and converts exactly the logs no recorded shard holds: nothing
is lost or duplicated, and as recorded shards hold a prefix of the list (less failed and skipped logs, which the rerun
tries again), the rerun ends with the folder an uninterrupted run writes. A log that raises loses its fragment and is
reported in ``errors.jsonl``; the others go on, and so do records the adapter's ``list_logs`` found unreadable
(``Adapter.bad_records``); both make ``ok`` False. Errors and skipped logs are reported in list order too.

A folder belongs to one adapter, version and set of options (``convert.json``, written before the first shard): resuming
with others would mix two conversions in one manifest, so it is refused unless ``force``. Inputs are checked (``src``
exists, holds logs) before ``out`` is created. Local workers end with their driver
(:func:`lead_s2r.processes.exit_with_parent`) and Ray cancels a dead driver's tasks, so a killed driver leaves no
orphans converting into the folder. Ray's cancelling takes a moment: a task of the dead run that is still ending writes
or deletes only its own run's fragments, never the rerun's, and what it leaves is gone when the rerun ends.
"""

import json
import os
import secrets
import shutil
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from lead_s2r import __version__
from lead_s2r.errors import UserError
from lead_s2r.files import write_text
from lead_s2r.processes import Executor, WorkerDied, make_executor
from lead_s2r.registry import Adapter, LogRef, SkipLog
from lead_s2r.schema import SCHEMA_VERSION, SchemaError, validate
from lead_s2r.shards import (
    ERRORS,
    IDENTITY,
    INFO,
    MANIFEST,
    SHARD_DIR,
    ShardFile,
    value_range,
    write_manifest,
    write_sample,
)

if TYPE_CHECKING:
    import pyarrow as pa

PROGRESS = "progress.jsonl"


@dataclass
class ConvertResult:
    """What a conversion did; ``ok`` is False when any log failed or any bad record was left out."""

    out: Path
    samples: int = 0
    logs_converted: int = 0
    logs_resumed: int = 0
    errors: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[dict[str, Any]] = field(default_factory=list)
    bad_records: list[dict[str, Any]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors and not self.bad_records


def manifest_row(sample: dict[str, Any]) -> dict[str, Any]:
    """The manifest row of one sample but its shard (:func:`_in_shard`): identity, a few scalars for filtering and
    statistics, has_* flags."""
    meta = sample["meta"]
    tp = sample.get("target_points")
    current_tp = tp[1] if tp is not None else (np.nan, np.nan)
    row = {
        "key": sample["__key__"],
        "dataset": meta["dataset"],
        "split": meta["split"],
        "log": meta["log_id"],
        "frame": int(meta["frame_idx"]),
        "timestamp_us": int(meta["timestamp_us"]),
        "speed": float(meta["ego"]["speed"]),
        "command": int(meta["ego"]["command"]),
        "tp_x": float(current_tp[0]),
        "tp_y": float(current_tp[1]),
        "tags": list(meta.get("tags", [])),
    }
    row.update({f"has_{name}": bool(flag) for name, flag in meta["has"].items()})
    return row


def _in_shard(row: dict[str, Any], shard: str) -> dict[str, Any]:
    """A manifest row with its shard, second after the key: a log's rows are made before its shard is known."""
    return {"key": row["key"], "shard": shard, **row}


# --------------------------------------------------------------------------- worker side


def _fragment_path(out: Path, run: str, position: int) -> Path:
    """Where the log at ``position`` of run ``run``'s list is written before it joins a shard; a ``.partial`` name
    that no recorded shard has, so the cleanup of a rerun deletes it."""
    return out / SHARD_DIR / f"log-{position:06d}.{run}.partial"


def _convert_log(adapter: Adapter, log: LogRef, fragment: Path) -> list[dict[str, Any]]:
    """Write every sample of ``log`` to ``fragment``; on any exception the fragment is deleted."""
    rows = []
    try:
        with open(fragment, "wb") as file:
            for sample in adapter.iter_samples(log):
                validate(sample)
                write_sample(file, sample)
                rows.append(manifest_row(sample))
    except BaseException:
        fragment.unlink(missing_ok=True)
        raise
    return rows


def _run_log(adapter: Adapter, out: Path, run: str, position: int, log: LogRef) -> tuple[str, int, Any]:
    """Convert one log into its fragment: ``("done", position, rows)``, ``("skipped", position, reason)`` or
    ``("error", position, message)``."""
    try:
        return "done", position, _convert_log(adapter, log, _fragment_path(out, run, position))
    except SkipLog as reason:
        return "skipped", position, str(reason)
    except UserError as err:  # a bad source file: the adapter's message names it; a SchemaError names a sample only
        source = f"{log.path}: " if isinstance(err, SchemaError) else ""
        return "error", position, f"{type(err).__name__}: {source}{err.one_line()}"
    except Exception as err:  # every failure of one log is isolated and reported; a bug keeps its code line
        where = traceback.extract_tb(err.__traceback__)[-1]
        return "error", position, f"{type(err).__name__}: {err} (at {Path(where.filename).name}:{where.lineno})"


def one_thread_per_worker() -> None:
    """Processes are the parallelism: a native pool per worker (lazrs' rayon LAZ decoder, OpenCV) would
    oversubscribe the cores the other workers use. Rayon reads its variable when its pool first starts."""
    os.environ["RAYON_NUM_THREADS"] = "1"
    cv2.setNumThreads(1)


# --------------------------------------------------------------------------- main side


def _prepare(out: Path, force: bool, identity: dict[str, Any]) -> list[dict[str, Any]]:
    """Make ``out`` ready: wipe it with ``force``, else refuse another conversion's folder, drop partial and
    unrecorded shards and keep the records."""
    if force and out.exists():
        for name in (SHARD_DIR, PROGRESS, MANIFEST, INFO, ERRORS, IDENTITY):
            target = out / name
            if target.is_dir():
                shutil.rmtree(target)
            else:
                target.unlink(missing_ok=True)
    _check_identity(out, identity)
    try:
        (out / SHARD_DIR).mkdir(parents=True, exist_ok=True)
        write_text(out / IDENTITY, json.dumps(identity, indent=2) + "\n")
    except OSError as err:
        raise UserError(f"--out {out}: cannot write there ({err.strerror or err}); choose a writable folder") from None
    records = []
    lines = (out / PROGRESS).read_text().splitlines() if (out / PROGRESS).exists() else []
    for line in lines:
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:  # a torn last line: killed while appending
            break
    _drop_unrecorded(out, records)
    with open(out / PROGRESS, "w") as file:  # rewrite without a torn tail
        file.writelines(json.dumps(record) + "\n" for record in records)
    return records


def _drop_unrecorded(out: Path, records: list[dict[str, Any]]) -> None:
    """Delete every file of the shard folder that no record names; one may vanish meanwhile (a task of a killed run,
    ending, deletes its own fragment)."""
    recorded = {record["shard"] for record in records}
    for path in (out / SHARD_DIR).iterdir():
        if path.name not in recorded:
            path.unlink(missing_ok=True)


def identity_of(adapter: Adapter) -> dict[str, Any]:
    """What makes two conversions compatible: adapter name, version and options (JSON-ready)."""
    options = json.loads(json.dumps(adapter.options(), default=str))
    return {"adapter": adapter.name, "adapter_version": adapter.version, "options": options}


def _check_identity(out: Path, identity: dict[str, Any]) -> None:
    """Refuse to resume into a folder that another adapter, version or option set converted."""
    if (out / IDENTITY).exists():
        recorded = json.loads((out / IDENTITY).read_text())
    elif (out / INFO).exists():  # converted before convert.json existed: only the adapter is known
        recorded = {"adapter": json.loads((out / INFO).read_text()).get("adapter")}
        identity = {"adapter": identity["adapter"]}
    else:
        return
    if recorded == identity:
        return
    raise UserError(
        f"--out {out} holds a conversion by {_differences(recorded, identity)}: "
        "pass --force to start over there, or choose a new --out"
    )


def _differences(recorded: dict[str, Any], identity: dict[str, Any]) -> str:
    """``"carla_lead 2 (rig='both'), but this run asks for carla_lead 2 (rig='normal')"``: only what differs."""

    def describe(entry: dict[str, Any], names: list[str]) -> str:
        options = entry.get("options") or {}
        shown = ", ".join(f"{name}={options.get(name)!r}" for name in names)
        return f"{entry.get('adapter')} {entry.get('adapter_version', '')}".strip() + (f" ({shown})" if shown else "")

    old, new = recorded.get("options") or {}, identity.get("options") or {}
    names = sorted(name for name in {*old, *new} if old.get(name) != new.get(name))
    if recorded.get("adapter") != identity.get("adapter"):
        names = []  # options of two adapters do not compare
    return f"{describe(recorded, names)}, but this run asks for {describe(identity, names)}"


def _list_logs(adapter: Adapter, src: Path, limit_logs: int | None) -> list[LogRef]:
    """The logs to convert; a missing or empty ``src``, or one where the adapter finds nothing, is a UserError."""
    if not src.exists():
        raise UserError(f"--src {src} does not exist; give the folder of raw {adapter.name} data")
    if src.is_dir() and not any(src.iterdir()):
        raise UserError(f"--src {src} is an empty folder; give the folder of raw {adapter.name} data")
    try:
        logs = adapter.list_logs(src)
    except (FileNotFoundError, NotADirectoryError) as err:
        raise UserError(f"--src {src}: {err}; see docs/datasets/{adapter.name}.md for the layout") from None
    if not logs:
        raise UserError(
            f"--src {src}: the {adapter.name} adapter finds no logs there; see docs/datasets/{adapter.name}.md"
        )
    return logs if limit_logs is None else logs[:limit_logs]


def _next_shard_index(records: list[dict[str, Any]]) -> int:
    indices = [int(record["shard"].rsplit("-", 1)[1].split(".")[0]) for record in records]
    return max(indices, default=-1) + 1


def conversion_executor(workers: int = 1, executor: str = "processes", address: str | None = None) -> Executor:
    """The executor of ``workers`` local processes (this one alone for 1), or of the Ray cluster at ``address``."""
    return make_executor(workers, executor, address, preload=[__name__], initializer=one_thread_per_worker)


def _in_list_order(messages: Iterator[tuple[str, int, Any]]) -> Iterator[tuple[bool, tuple[str, int, Any]]]:
    """``(True, message)`` for each message as it comes (progress), then ``(False, message)`` for each in the order
    of positions as soon as every earlier position has come (assembly)."""
    waiting: dict[int, tuple[str, int, Any]] = {}
    next_position = 0
    for message in messages:
        yield True, message
        waiting[message[1]] = message
        while next_position in waiting:
            yield False, waiting.pop(next_position)
            next_position += 1


class _Assembler:
    """Appends converted logs' fragments, in the order of the log list, to shards named from ``index`` on, closing a
    shard once it holds ``shard_size`` samples: the shards one process converting the logs in turn would write."""

    def __init__(
        self, out: Path, prefix: str, shard_size: int, index: int, record: Callable[[dict[str, Any]], None]
    ) -> None:
        self.out, self.prefix, self.shard_size, self.index, self.record = out, prefix, shard_size, index, record
        self.shard: ShardFile | None = None
        self.logs: list[tuple[str, list[dict[str, Any]]]] = []

    def add(self, fragment: Path, log_id: str, rows: list[dict[str, Any]]) -> None:
        """Append a log's fragment and delete it: until its shard is recorded, a rerun converts the log again."""
        if self.shard is None:
            self.shard = ShardFile(self.out / SHARD_DIR / f"{self.prefix}-{self.index:06d}.tar")
            self.index += 1
        self.shard.append(fragment, len(rows))
        fragment.unlink()
        self.logs.append((log_id, rows))
        if self.shard.count >= self.shard_size:
            self.flush()

    def flush(self) -> None:
        """Close the open shard (dropping it if empty), then record it with its logs and their manifest rows."""
        if self.shard is None:
            return
        if self.shard.count == 0:
            self.shard.abort()
        else:
            name = self.shard.close().name
            logs = [(log_id, [_in_shard(row, name) for row in rows]) for log_id, rows in self.logs]
            self.record({"shard": name, "logs": logs})
        self.shard, self.logs = None, []

    def abort(self) -> None:
        if self.shard is not None:
            self.shard.abort()


def convert(
    adapter: Adapter,
    src: str | Path,
    out: str | Path,
    workers: int = 1,
    shard_size: int = 1000,
    limit_logs: int | None = None,
    force: bool = False,
    progress: bool = False,
    executor: Executor | None = None,
) -> ConvertResult:
    """Convert every log of ``src`` with ``adapter`` into ``out`` (see the module docstring for the guarantees).
    ``workers`` counts the processes converting on this machine (1: this process alone; more: that many workers
    while this process assembles shards); ``executor`` replaces them (``RayExecutor`` for a cluster); a shard is
    closed at the first log boundary after ``shard_size`` samples."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn  # see _finish

    src, out = Path(src), Path(out)
    logs = _list_logs(adapter, src, limit_logs)
    records = _prepare(out, force, identity_of(adapter))
    run = secrets.token_hex(4)
    done = {log_id for record in records for log_id, _ in record["logs"]}
    todo = [log for log in logs if log.log_id not in done]
    result = ConvertResult(out=out, logs_resumed=len(logs) - len(todo), bad_records=adapter.bad_records())
    started = time.perf_counter()
    with (
        open(out / PROGRESS, "a") as journal,
        open(out / ERRORS, "w") as errors,
        Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[samples]} samples, {task.fields[rate]:.1f}/s"),
            TimeElapsedColumn(),
            disable=not progress,
        ) as bar,
    ):
        errors.writelines(json.dumps({**record, "adapter": adapter.name}) + "\n" for record in result.bad_records)
        task = bar.add_task(f"{adapter.name} logs", total=len(todo), samples=0, rate=0.0)

        def record(entry: dict[str, Any]) -> None:
            journal.write(json.dumps(entry) + "\n")
            journal.flush()
            os.fsync(journal.fileno())
            records.append(entry)

        assembler = _Assembler(out, adapter.name, shard_size, _next_shard_index(records), record)
        jobs = [(adapter, out, run, position, log) for position, log in enumerate(todo)]
        try:
            results = (executor or conversion_executor(workers)).run(_run_log, jobs)  # in the order logs finish
            for arrived, (kind, position, payload) in _in_list_order(message for _, message in results):
                if arrived:
                    result.samples += len(payload) if kind == "done" else 0
                    rate = result.samples / max(time.perf_counter() - started, 1e-9)
                    bar.update(task, advance=1, samples=result.samples, rate=rate)
                    continue
                log_id = todo[position].log_id
                if kind == "done":
                    result.logs_converted += 1
                    assembler.add(_fragment_path(out, run, position), log_id, payload)
                elif kind == "skipped":
                    result.skipped.append({"log": log_id, "reason": payload})
                else:
                    entry = {"log": log_id, "error": payload, "adapter": adapter.name}
                    result.errors.append(entry)
                    errors.write(json.dumps(entry) + "\n")
                    errors.flush()
            assembler.flush()
        except WorkerDied as err:  # a crash, or Ray's retries spent: the run ends, a rerun resumes it
            raise RuntimeError(f"a conversion worker died; rerun the same command to resume ({err})") from err
        finally:
            assembler.abort()
    _drop_unrecorded(out, records)
    _finish(adapter, src, out, records, result)
    return result


def _finish(adapter: Adapter, src: Path, out: Path, records: list[dict[str, Any]], result: ConvertResult) -> None:
    """Write ``manifest.parquet`` and ``info.json`` from every recorded shard (this run's and earlier ones).
    pyarrow and rich are imported in the driver's functions only: the workers' forkserver imports this module, and
    they are 0.2 s of its start-up."""
    import pyarrow as pa

    rows = [row for record in records for _, log_rows in record["logs"] for row in log_rows]
    flags = sorted({name for row in rows for name in row if name.startswith("has_")})
    for row in rows:
        for name in flags:
            row.setdefault(name, False)
    table = pa.Table.from_pylist(rows) if rows else pa.table({"key": pa.array([], pa.string())})
    write_manifest(out, table)
    info = {
        "schema_version": SCHEMA_VERSION,
        "lead_s2r_version": __version__,
        "adapter": adapter.name,
        "adapter_version": adapter.version,
        "adapter_options": identity_of(adapter)["options"],
        "source": str(src),
        "counts": {
            "samples": len(rows),
            "logs": len({row["log"] for row in rows}),
            "by_split": dict(Counter(row["split"] for row in rows)),
        },
        "shards": {record["shard"]: sum(len(r) for _, r in record["logs"]) for record in records},
        "statistics": _statistics(table) if rows else {},
        "skipped_logs": result.skipped,
        "failed_logs": len(result.errors),
        "bad_records": len(result.bad_records),
        **adapter.describe(),
    }
    write_text(out / INFO, json.dumps(info, indent=2, allow_nan=False))


def _statistics(table: "pa.Table") -> dict[str, Any]:
    """Ranges of the data with their 1st/99th percentiles, for people reading info.json (models normalise by their
    own constants: LEAD divides target points by (200, 50))."""
    stats: dict[str, Any] = {}
    for column in ("speed", "tp_x", "tp_y"):
        values = table[column].to_numpy(zero_copy_only=False).astype(np.float64)
        summary = value_range(values)
        if summary is not None:
            p01, p99 = np.percentile(values[np.isfinite(values)], [1, 99])
            stats[column] = summary | {"p01": float(p01), "p99": float(p99)}
    return stats
