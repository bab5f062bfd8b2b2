"""One owner per idea (DESIGN.md §1), read from the source with ``ast`` like the import rules: the typed-fields check
lives in lead_s2r/fields.py, renames in lead_s2r/files.py, and each artifact's file name in its owner module (the
only place that can then parse it), and nowhere else. Each rule is also shown to catch a
planted violation, so a rule that silently stopped matching would fail here."""

import ast
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted([*(ROOT / "lead_s2r").rglob("*.py"), *(ROOT / "adapters").rglob("*.py")])
#: a finding: (line, what was found)
Finding = tuple[int, str]


def _isinstance_of(node: ast.AST) -> list[str]:
    """The type names an ``isinstance(x, ...)`` call tests (``int | float`` and tuples flattened), else []."""
    if not (isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance" and len(node.args) == 2):
        return []
    names, pending = [], [node.args[1]]
    while pending:
        part = pending.pop()
        if isinstance(part, ast.BinOp):
            pending += [part.left, part.right]
        elif isinstance(part, ast.Tuple):
            pending += part.elts
        elif isinstance(part, ast.Name | ast.Attribute):
            names.append(part.id if isinstance(part, ast.Name) else part.attr)
    return names


def hand_written_type_checks(tree: ast.AST) -> Iterator[Finding]:
    """ "A bool is no number" written by hand: one boolean expression testing ``isinstance(x, bool)`` and
    ``isinstance(x, int | float ...)`` (lead_s2r.fields.fits / is_number say it once)."""
    for node in ast.walk(tree):
        if not isinstance(node, ast.BoolOp):
            continue
        tested = [name for part in ast.walk(node) for name in _isinstance_of(part)]
        if "bool" in tested and {"int", "float", "Integral", "Real", "integer", "floating"} & set(tested):
            yield node.lineno, "isinstance(..., bool) beside a number check: use lead_s2r.fields"


def renames(tree: ast.AST) -> Iterator[Finding]:
    """``os.replace`` / ``os.rename`` / ``shutil.move`` / ``Path.rename`` outside the atomic-write helper."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            owner = getattr(node.func.value, "id", None)
            if (owner, node.func.attr) in {("os", "replace"), ("os", "rename"), ("shutil", "move")} or (
                node.func.attr == "rename"
            ):
                yield node.lineno, f"{owner or '...'}.{node.func.attr}: write through lead_s2r.files"


def file_name(name: str) -> Callable[[ast.AST], Iterator[Finding]]:
    """A finder of the string ``name`` as a path or a path's last part (``"scores.json"``, ``"out/scores.json"``,
    ``"**/scores.json"``, an f-string's piece): a reader or writer of that artifact outside its owner. Prose that
    mentions the file (a message, a docstring) has spaces and is no path."""

    def finder(tree: ast.AST) -> Iterator[Finding]:
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                text = node.value.strip()
                if " " not in text and (text == name or text.endswith(f"/{name}")):
                    yield node.lineno, f"{text!r}: read and write {name} through its owner module"

    return finder


#: (rule, the one module allowed to do it, the finder)
RULES: list[tuple[str, str, Callable[[ast.AST], Iterator[Finding]]]] = [
    ("the typed-fields check has one definition", "lead_s2r/fields.py", hand_written_type_checks),
    ("files are put in place by the atomic-write helper alone", "lead_s2r/files.py", renames),
    ("scores.json has one owner", "lead_s2r/scoring/scores_file.py", file_name("scores.json")),
    ("scores.parquet has one owner", "lead_s2r/scoring/scores_file.py", file_name("scores.parquet")),
    ("the training log has one owner", "lead_s2r/report/training_log.py", file_name("metrics.csv")),
    ("a conversion's manifest has one owner", "lead_s2r/shards.py", file_name("manifest.parquet")),
]


def violations(finder: Callable[[ast.AST], Iterator[Finding]], owner: str, paths: list[Path]) -> list[str]:
    found = []
    for path in paths:
        name = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else path.name
        if name != owner:
            found += [f"{name}:{line}: {what}" for line, what in finder(ast.parse(path.read_text(), str(path)))]
    return found


@pytest.mark.parametrize(("rule", "owner", "finder"), RULES, ids=[rule[0] for rule in RULES])
def test_one_owner(rule: str, owner: str, finder: Callable[[ast.AST], Iterator[Finding]]) -> None:
    assert (ROOT / owner).is_file() and len(SOURCES) > 100  # the walk sees the package
    broken = violations(finder, owner, SOURCES)
    if broken:
        pytest.fail(f"{rule}:\n  " + "\n  ".join(broken), pytrace=False)


@pytest.mark.parametrize(
    ("finder", "planted"),
    [
        (hand_written_type_checks, "def f(v):\n    return isinstance(v, int | float) and not isinstance(v, bool)\n"),
        (hand_written_type_checks, "def f(v):\n    if isinstance(v, bool) or not isinstance(v, int):\n        pass\n"),
        (renames, "import os\nos.replace('a', 'b')\n"),
        (renames, "from pathlib import Path\nPath('a').rename('b')\n"),
        (
            file_name("scores.json"),
            "import json\ndef f(run):\n    return json.loads((run / 'scores.json').read_text())\n",
        ),
        (file_name("scores.json"), "def f(run):\n    return sorted(run.rglob('**/scores.json'))\n"),
        (file_name("scores.parquet"), "def f(out):\n    return f'{out}/scores.parquet'\n"),
        (file_name("metrics.csv"), "def f(run):\n    return run / 'lightning_logs/version_0/metrics.csv'\n"),
    ],
)
def test_a_planted_violation_is_caught(
    tmp_path: Path, finder: Callable[[ast.AST], Iterator[Finding]], planted: str
) -> None:
    module = tmp_path / "planted.py"
    module.write_text(planted)
    assert violations(finder, "lead_s2r/fields.py", [module])
    clean = 'def f(v):\n    """Reads metrics.csv."""\n    return isinstance(v, bool), "no scores.json below"\n'
    (tmp_path / "clean.py").write_text(clean)
    assert not violations(finder, "lead_s2r/fields.py", [tmp_path / "clean.py"])
