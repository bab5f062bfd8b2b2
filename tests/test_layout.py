"""The package's files stay small enough to have one job each (STYLE.md): none over 500 lines."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 500


def test_no_module_over_500_lines() -> None:
    sizes = {
        path.relative_to(ROOT).as_posix(): len(path.read_text().splitlines())
        for folder in ("lead_s2r", "adapters")
        for path in sorted((ROOT / folder).rglob("*.py"))
    }
    assert len(sizes) > 100  # the walk found the package
    too_long = {name: lines for name, lines in sizes.items() if lines > MAX_LINES}
    assert not too_long, f"split these by job (over {MAX_LINES} lines): {too_long}"
