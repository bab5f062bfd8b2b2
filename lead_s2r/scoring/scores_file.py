"""One scoring's output: ``scores.json`` (aggregates, metric, config, inputs) beside ``scores.parquet`` (a row per
scored sample), written by ``lead-s2r score`` / ``carla-metrics``, read by ``lead-s2r report`` / ``table``. The one
module that spells the names or parses the files (tests/test_owners.py): the readers once checked it two ways."""

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa

from lead_s2r.errors import UserError
from lead_s2r.fields import check_fields
from lead_s2r.files import read_parquet, write_parquet, write_text

SCORES_JSON = "scores.json"
SCORES_TABLE = "scores.parquet"
#: The fields of every scores.json and their JSON types (``metric`` is required; a missing ``tag`` is null).
FIELDS: dict[str, Any] = {"metric": str, "tag": str | None, "aggregates": dict}
#: What ``lead-s2r score`` adds and the report reads: the predictions it draws, the data and configuration scored.
SCORED_FIELDS: dict[str, Any] = {"predictions": str, "data": list[str], "config": dict}
ADVICE = "not what `lead-s2r score` or `lead-s2r carla-metrics` writes there"


@dataclass
class ScoresFile:
    """A scoring's output folder: the scores.json content and, read with its rows or to be written, the table."""

    folder: Path
    report: dict[str, Any]
    table: pa.Table | None = None

    def write(self) -> dict[str, Any]:
        """Write ``scores.parquet`` (with a CRC32 per data page, which the readers check) and ``scores.json``
        (strict JSON: no NaN), each put in place whole; return the JSON content as a reader sees it."""
        if self.table is None:
            raise ValueError(f"{self.folder}: scores without their table")
        text = json.dumps(self.report, indent=2, allow_nan=False)
        write_parquet(self.folder / SCORES_TABLE, self.table)
        write_text(self.folder / SCORES_JSON, text + "\n")
        return json.loads(text)

    @classmethod
    def read(cls, folder: Path, rows: bool = True, error: type[Exception] = UserError) -> "ScoresFile":
        """The scores in ``folder``, checked: the JSON's fields have their types and, with ``rows``, the table is
        whole (every page's CRC) and keyed by sample; anything else is ``error`` with one line naming the file."""
        json_path = folder / SCORES_JSON
        try:
            report = json.loads(json_path.read_bytes())
            table = read_parquet(folder / SCORES_TABLE) if rows else None
        except (OSError, ValueError, pa.ArrowException) as err:  # ValueError: UTF-8, JSON, base64 (read_parquet)
            where = f"{folder}: cannot read {SCORES_JSON} / {SCORES_TABLE}" if rows else f"{json_path}: cannot read it"
            raise error(f"{where} ({err})") from None
        check_fields(report, FIELDS, str(json_path), error, ADVICE, required=("metric",))
        if table is not None:
            check_fields(report, SCORED_FIELDS, str(json_path), error, ADVICE)
            check_fields(report.get("config", {}), {"reference_cache": str | None}, str(json_path), error, at="config")
            key = table.schema.field("key").type if "key" in table.column_names else None
            if key is None or not pa.types.is_string(key):
                what = "is missing" if key is None else f"holds {key}"
                raise error(f"{folder / SCORES_TABLE}: its key column {what}, not sample keys; {ADVICE}")
        return cls(folder, report, table)


def scores_folders(path: Path) -> list[Path]:
    """The folders below ``path`` (itself included) that hold a scores.json, in the order of their paths."""
    return [found.parent for found in sorted(path.rglob(SCORES_JSON))]
