"""A run's training log, ``metrics.csv``: Lightning's CSV logger writes it (a row per logged step, a column per metric,
blank where not logged), the report's and the quickstart's loss curves read it. The one module that spells the name
or parses the file (tests/test_owners.py)."""

import csv
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from lead_s2r.errors import UserError

TRAINING_LOG = "metrics.csv"


@dataclass(frozen=True)
class TrainingLog:
    """One ``metrics.csv``, read only (Lightning writes it)."""

    path: Path

    def read(self) -> Iterator[tuple[str, float, float]]:
        """(column, step, value) of every filled cell but the step and epoch columns. A file that is gone, not
        UTF-8, not CSV, without a step column, with a row longer than its header or a cell that is no number is a
        :class:`UserError` naming it."""
        try:
            with self.path.open(newline="") as file:
                reader = csv.DictReader(file)
                if reader.fieldnames is not None and "step" not in reader.fieldnames:
                    raise ValueError(f"no step column in its header {reader.fieldnames}")
                for row in reader:
                    if None in row:  # DictReader files the cells past the header's under None
                        raise ValueError(f"line {reader.line_num} has more cells than the header")
                    step = row.get("step")
                    for name, value in row.items():
                        if name not in ("step", "epoch") and value not in (None, "") and step not in (None, ""):
                            yield name, float(step), float(value)
        except (OSError, ValueError, csv.Error) as err:  # ValueError: bytes not UTF-8, or a cell that is no number
            raise UserError(f"{self.path}: not a Lightning CSV log ({err})") from None
