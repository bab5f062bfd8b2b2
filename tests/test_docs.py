"""The documented workflows run as written: every shell block marked runnable in README.md's "Use" section and in
docs/*.md runs, in order, in one temporary folder per page (with ``recipes/`` linked in, as in a checkout).

Marking, in the Markdown (an HTML comment, invisible on GitHub) on the line before a ```bash block:

- ``<!-- runnable -->``: run it; a failing command fails the test and shows its output.
- ``<!-- runnable: skip REASON -->``: a workflow that needs what CI lacks (a CARLA server, a GPU, a real dataset);
  reported as skipped with REASON.

Blocks without a marker are illustrations (full-scale commands with placeholders) and are not run.
"""

import os
import re
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(
    r"<!--\s*runnable(?::\s*skip\s+(?P<reason>.*?))?\s*-->\s*\n```(?:bash|sh)\n(?P<code>.*?)\n```", re.S
)
#: seconds one block may take before it counts as hung
BLOCK_TIMEOUT = 600


@dataclass(frozen=True)
class Block:
    page: str
    index: int
    code: str
    skip: str | None

    @property
    def id(self) -> str:
        return f"{self.page}#{self.index}"


def blocks_of(page: str, text: str) -> list[Block]:
    """The marked shell blocks of one page, in order."""
    return [Block(page, i, match["code"], match["reason"]) for i, match in enumerate(MARKER.finditer(text), start=1)]


def use_section(readme: str) -> str:
    """README.md's "## Use" section: the only part of the README whose commands a reader types in order."""
    start = readme.index("\n## Use\n")
    end = readme.find("\n## ", start + 1)
    return readme[start : end if end != -1 else len(readme)]


def documented_blocks() -> list[Block]:
    found = blocks_of("README.md", use_section((ROOT / "README.md").read_text()))
    for page in sorted((ROOT / "docs").glob("*.md")):
        found += blocks_of(f"docs/{page.name}", page.read_text())
    return found


def run_block(code: str, folder: Path) -> subprocess.CompletedProcess:
    """``code`` in bash (-e, -u, pipefail) in ``folder``, with this interpreter's ``lead-s2r`` first on PATH."""
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    return subprocess.run(
        ["bash", "-euo", "pipefail", "-c", code],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=BLOCK_TIMEOUT,
    )


@pytest.fixture(scope="module")
def page_folder(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Path]:
    """One working folder per page, shared by its blocks (each consumes what the one before it wrote)."""
    folders: dict[str, Path] = {}

    def folder_of(page: str) -> Path:
        if page not in folders:
            folders[page] = tmp_path_factory.mktemp(page.replace("/", "_").removesuffix(".md"))
            (folders[page] / "recipes").symlink_to(ROOT / "recipes")
        return folders[page]

    return folder_of


BLOCKS = documented_blocks()


def test_every_page_with_commands_has_runnable_or_explained_blocks() -> None:
    pages = {block.page for block in BLOCKS}
    assert {"README.md", "docs/closed_loop.md"} <= pages  # the chained Use block and the offline agent check


@pytest.mark.parametrize("block", BLOCKS, ids=[block.id for block in BLOCKS])
def test_documented_block_runs(block: Block, page_folder: Callable[[str], Path]) -> None:
    if block.skip:
        pytest.skip(block.skip)
    done = run_block(block.code, page_folder(block.page))
    output = f"{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    assert done.returncode == 0, f"{block.id} failed with status {done.returncode}:\n{block.code}\n{output}"


def test_a_broken_command_fails_and_a_skip_marker_carries_its_reason(tmp_path: Path) -> None:
    text = (
        "<!-- runnable -->\n```bash\necho one > a.txt\nlead-s2r nope\necho never\n```\n"
        "```bash\nnot marked\n```\n<!-- runnable: skip needs a CARLA server -->\n```bash\nCarlaUE4.sh\n```\n"
    )
    first, second = blocks_of("page.md", text)
    assert (first.skip, second.skip, second.code) == (None, "needs a CARLA server", "CarlaUE4.sh")
    done = run_block(first.code, tmp_path)
    assert done.returncode == 2 and (tmp_path / "a.txt").exists() and "never" not in done.stdout
