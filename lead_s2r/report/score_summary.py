"""What ``lead-s2r score`` prints: the headline, the sub-scores and where the frames went, in one short table.

scores.json holds everything (config, every unpredicted key, per-group breakdowns); a person reading the terminal
wants the aggregate first and the frame counts that explain it, so the table shows those and points at the file.
"""

from typing import Any

from rich.table import Table

#: rows of the table at most; what does not fit is counted and left to scores.json.
MAX_ROWS = 24


def _number(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4f}"
    return "-" if value is None else str(value)


def summary_rows(report: dict[str, Any]) -> list[tuple[str, str]]:
    """(label, value) rows: aggregate scores (a nested breakdown indented under its name), then frame counts and
    the predictions left aside. A breakdown of breakdowns (``per_dataset``) shows each group's first value."""
    scores: list[tuple[str, str]] = []
    counts: list[tuple[str, str]] = []
    for name, value in report["aggregates"].items():
        if isinstance(value, dict):
            scores.append((name, ""))
            for group, inner in value.items():
                shown = next(iter(inner.items())) if isinstance(inner, dict) and inner else (None, inner)
                label = f"  {group}" if shown[0] is None else f"  {group}: {shown[0]}"
                scores.append((label, _number(shown[1])))
        elif name == "frames" or name.startswith("frames_"):
            counts.append((name.replace("_", " "), _number(value)))
        else:
            scores.append((name, _number(value)))
    unpredicted = report.get("unpredicted", {}).get("count", 0)
    if unpredicted:
        counts.append(("frames without a prediction (left out)", str(unpredicted)))
    for dataset, count in report.get("other_datasets", {}).items():
        counts.append((f"predictions of {dataset} (not in --data)", str(count)))
    rows = scores + counts
    if len(rows) > MAX_ROWS:
        rows = [*rows[: MAX_ROWS - 1], (f"... {len(rows) - MAX_ROWS + 1} more rows", "see scores.json")]
    return rows


def score_table(report: dict[str, Any]) -> Table:
    """The rich table ``lead-s2r score`` prints (headline first)."""
    split = f", split {report['split']}" if report.get("split") else ""
    table = Table(title=f"{report['metric']} ({report['metric_version']}{split})", show_header=False)
    table.add_column("", style="bold")
    table.add_column("", justify="right")
    for label, value in summary_rows(report):
        table.add_row(label, value)
    return table
