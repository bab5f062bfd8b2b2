"""CI runs README's test command as written and fails on any skip not in tests/skips_allowed.txt."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CHECK = ROOT / ".ci" / "check_skips.py"


def readme_test_command() -> str:
    """The bash block under README's "Run the tests:"."""
    readme = (ROOT / "README.md").read_text()
    found = re.search(r"Run the tests:\n\n```bash\n(?P<command>.*?)\n```", readme, re.S)
    assert found, "README.md has no 'Run the tests:' bash block"
    return found["command"]


def test_ci_runs_readmes_test_command_verbatim() -> None:
    command = readme_test_command()
    assert "pytest" in command and command in (ROOT / ".ci" / "run").read_text()


def check(tmp_path: Path, output: str) -> subprocess.CompletedProcess:
    log = tmp_path / "pytest.log"
    log.write_text(output)
    return subprocess.run([sys.executable, str(CHECK), str(log)], capture_output=True, text=True, check=False)


ALLOWED = "SKIPPED [2] tests/test_docs.py:100: needs a CARLA 0.9.15 server and the leaderboard"


@pytest.mark.parametrize(
    ("summary", "final", "status"),
    [
        ([ALLOWED], "10 passed, 2 skipped, 3 warnings in 5.10s", 0),
        ([], "10 passed, 1 warning in 5.10s", 0),
        ([ALLOWED, "SKIPPED [1] tests/test_report.py:212: no chromium binary on PATH"], "9 passed, 3 skipped in 1s", 1),
        ([], "10 passed, 2 skipped in 5.10s", 1),  # the summary's lines missing: -ra dropped from addopts
        (["SKIPPED [1] tests/test_docs.py:100: needs a CARLA 0.9.15 server"], "1 skipped in 0.50s", 1),  # reason cut
        (["\x1b[33mSKIPPED\x1b[0m [2] tests/test_docs.py:100: needs a CARLA 0.9.15 server and the leaderboard"],
         "\x1b[32m5 passed\x1b[0m, \x1b[33m2 skipped\x1b[0m in 1.00s", 0),  # coloured output
    ],
)  # fmt: skip
def test_a_skip_fails_ci_unless_listed_with_its_reason(tmp_path: Path, summary: list[str], final: str, status: int):
    output = "\n".join(["....s..s", "=== short test summary info ===", *summary, final, ""])
    done = check(tmp_path, output)
    assert done.returncode == status, done.stdout + done.stderr
    if status:
        assert "not in" in done.stderr or "counted" in done.stderr


def test_every_allowed_skip_names_a_test_file_and_a_reason() -> None:
    lines = (ROOT / "tests" / "skips_allowed.txt").read_text().splitlines()
    for line in (line for line in lines if line.strip() and not line.startswith("#")):
        file, _, reason = line.partition(": ")
        assert (ROOT / file).is_file() and reason.strip(), line
