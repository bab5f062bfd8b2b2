"""What several verb groups share: where jobs run, and leaving nothing half-written behind."""

import argparse
import contextlib
import shutil
from collections.abc import Iterator
from pathlib import Path


def add_executor_arguments(parser: argparse.ArgumentParser, workers_help: str) -> None:
    """``--workers``, ``--executor``, ``--address``: where ``convert``, ``score`` and ``vocab score`` run their jobs."""
    parser.add_argument("--workers", type=int, default=1, help=workers_help)
    parser.add_argument(
        "--executor",
        choices=["processes", "ray"],
        default="processes",
        help="processes: --workers on this machine; ray: a task per job on a Ray cluster (pip install lead-s2r[ray])",
    )
    parser.add_argument(
        "--address", default=None, help="with --executor ray: auto, or HOST:PORT of the head (default: RAY_ADDRESS)"
    )


@contextlib.contextmanager
def removed_on_failure(out: Path) -> Iterator[None]:
    """What the block writes under ``out`` is removed if it fails (``out`` too, if the block made it): a planner's
    predictions or a scores.parquet without its scores.json must not pass for a result."""
    before = set(out.rglob("*")) if out.exists() else None
    try:
        yield
    except BaseException:
        if before is None:
            shutil.rmtree(out, ignore_errors=True)
        else:
            for path in sorted(set(out.rglob("*")) - before, reverse=True):  # a folder's files before the folder
                path.rmdir() if path.is_dir() else path.unlink()
        raise
