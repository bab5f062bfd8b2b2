"""Fail CI on a skipped test that the allow-list does not name: a test that skips in CI never runs anywhere.

Reads pytest's console output (README's test command, kept verbatim in ``.ci/run`` and teed to a file): the
``SKIPPED [N] FILE:LINE: REASON`` lines of its short summary (``-ra`` in pyproject's addopts) and the final count.
A skip is allowed when ``tests/skips_allowed.txt`` lists its file and reason as ``FILE: REASON``. The summary's
skips must add up to the final line's ``N skipped``, so output without the summary (``-ra`` dropped) fails too.
Standard library only: it runs with the system's ``python3``, whatever the test venv holds.
"""

import re
import sys
from pathlib import Path

ALLOW_LIST = Path(__file__).resolve().parent.parent / "tests" / "skips_allowed.txt"
ANSI = re.compile(r"\x1b\[[0-9;]*m")
SKIP_LINE = re.compile(r"^SKIPPED \[(?P<count>\d+)\] (?P<file>[^:]+)(?::\d+)?: (?P<reason>.*)$")
FINAL_LINE = re.compile(r"^=*\s*(\d+ \w+|no tests ran)\b.* in [\d.]+s\b")
FINAL_COUNT = re.compile(r"\b(?P<count>\d+) skipped\b")


def allowed_skips(path: Path) -> set[tuple[str, str]]:
    """The (file, reason) pairs of the allow-list: one ``FILE: REASON`` per line, ``#`` starts a comment line."""
    pairs = set()
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        file, separator, reason = line.partition(": ")
        if not separator or not reason.strip():
            sys.exit(f"{path}:{number}: not 'FILE: REASON': {line!r}")
        pairs.add((file.strip(), reason.strip()))
    return pairs


def reported_skips(output: str) -> tuple[list[tuple[str, str, int]], int]:
    """The skips of pytest's short summary as (file, reason, count), and the final line's skipped count."""
    lines = [ANSI.sub("", line).rstrip() for line in output.splitlines()]
    skips = [
        (match["file"], match["reason"].strip(), int(match["count"])) for match in map(SKIP_LINE.match, lines) if match
    ]
    final = next((line for line in reversed(lines) if FINAL_LINE.match(line)), "")
    found = FINAL_COUNT.search(final)
    return skips, int(found["count"]) if found else 0


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: check_skips.py PYTEST_OUTPUT", file=sys.stderr)
        return 2
    skips, total = reported_skips(Path(argv[0]).read_text(errors="replace"))
    allowed = allowed_skips(ALLOW_LIST)
    print(f"ci: pytest skipped {total} test(s); {ALLOW_LIST.name} allows:")
    unlisted = 0
    for file, reason, count in skips:
        listed = (file, reason) in allowed
        unlisted += 0 if listed else count
        print(f"  {'allowed' if listed else 'NOT ALLOWED'} [{count}] {file}: {reason}")
    if sum(count for *_, count in skips) != total:
        print(f"ci: the summary lists {sum(c for *_, c in skips)} skips but pytest counted {total}", file=sys.stderr)
        return 1
    if unlisted:
        print(f"ci: {unlisted} skipped test(s) not in {ALLOW_LIST}; make them run or list them", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
