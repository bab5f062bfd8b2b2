"""The package's layering (DESIGN.md §1, "Import rules"), read from the source with ``ast``: every import statement of
every module in lead_s2r/ and adapters/, function-local ones included, so a cycle hidden inside a function fails
as loudly as one at the top. Each failure names the offending import as ``file:line``."""

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: (folder, import name) of every package we check; adapters/ installs as ``lead_s2r_adapters``.
PACKAGES = ((ROOT / "lead_s2r", "lead_s2r"), (ROOT / "adapters", "lead_s2r_adapters"))
CONTRACTS = ("lead_s2r.schema", "lead_s2r.geometry", "lead_s2r.errors", "lead_s2r.fields", "lead_s2r.files")
LIGHTNING = ("lightning", "pytorch_lightning")


@dataclass(frozen=True)
class Import:
    """One imported module as written at ``file:line`` (``target`` resolved to a module where it names one)."""

    source: str
    target: str
    file: Path
    line: int

    def __str__(self) -> str:
        return f"{self.file.relative_to(ROOT)}:{self.line}: {self.source} imports {self.target}"


def module_names() -> dict[str, Path]:
    """Every module of our packages, by dotted name (a package by its ``__init__``)."""
    modules = {}
    for folder, package in PACKAGES:
        for path in sorted(folder.rglob("*.py")):
            parts = [package, *path.relative_to(folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> Iterator[Import]:
    """The imports of module ``name``; ``from package import submodule`` counts as importing the submodule."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield Import(name, alias.name, path, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            for alias in node.names:
                submodule = f"{base}.{alias.name}"
                yield Import(name, submodule if submodule in modules else base, path, node.lineno)


def in_layer(module: str, *layers: str) -> bool:
    return any(module == layer or module.startswith(f"{layer}.") for layer in layers)


def import_graph() -> list[Import]:
    modules = module_names()
    return [found for name, path in modules.items() for found in imports_of(name, path, modules)]


GRAPH = import_graph()
OURS = {edge.source for edge in GRAPH}

#: (rule, importing layer(s), forbidden target layer(s))
FORBIDDEN: list[tuple[str, tuple[str, ...], tuple[str, ...]]] = [
    ("adapters never import models, training, scoring or synthetic", ("lead_s2r_adapters",),
     ("lead_s2r.models", "lead_s2r.training", "lead_s2r.scoring", "lead_s2r.synthetic", *LIGHTNING)),
    ("scoring never imports models, training or Lightning", ("lead_s2r.scoring",),
     ("lead_s2r.models", "lead_s2r.training", "lead_s2r.data", *LIGHTNING)),
    ("models are plain nn.Modules: no data, training or Lightning", ("lead_s2r.models",),
     ("lead_s2r.data", "lead_s2r.training", "lead_s2r.scoring", *LIGHTNING)),
    ("synthetic never imports adapters (a writer and the reader it tests share no code)", ("lead_s2r.synthetic",),
     ("lead_s2r_adapters",)),
    ("the core finds adapters through entry points, never imports lead_s2r_adapters", ("lead_s2r",),
     ("lead_s2r_adapters",)),
    ("data/ reads shards, never raw datasets", ("lead_s2r.data",), ("lead_s2r.synthetic", "lead_s2r.formats")),
    ("submit/ reads predictions and converted data, never models", ("lead_s2r.submit",),
     ("lead_s2r.models", "lead_s2r.training", *LIGHTNING)),
    ("report/ reads run outputs and converted data, never trains", ("lead_s2r.report",), ("lead_s2r.training",)),
]  # fmt: skip


def fail_on(broken: list[Import], rule: str) -> None:
    """Fail naming ``rule`` and every offending import as ``file:line``."""
    if broken:
        pytest.fail(f"{rule}:\n  " + "\n  ".join(map(str, broken)), pytrace=False)


def test_the_graph_is_read() -> None:
    """The walk sees the package (a broken walk would make every rule below pass vacuously)."""
    assert {"lead_s2r.schema", "lead_s2r.scoring.pdm.score", "lead_s2r_adapters.navsim"} <= OURS
    assert any(edge.target == "lead_s2r.scoring.pdm.route" for edge in GRAPH if edge.source.endswith("pdm_closed"))


def test_no_import_cycle() -> None:
    edges: dict[str, list[Import]] = {}
    for edge in GRAPH:
        if edge.target in OURS and edge.target != edge.source:
            edges.setdefault(edge.source, []).append(edge)
    cycle = find_cycle(edges)
    if cycle:
        pytest.fail("import cycle:\n  " + "\n  ".join(map(str, cycle)), pytrace=False)


def find_cycle(edges: dict[str, list[Import]]) -> list[Import] | None:
    """One cycle of the graph as its imports, or None (depth-first search, iterative: the graph has ~200 nodes)."""
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    for root in sorted(edges):
        if state.get(root):
            continue
        path: list[Import] = []
        stack = [(root, iter(edges.get(root, [])))]
        state[root] = 1
        while stack:
            node, pending = stack[-1]
            edge = next(pending, None)
            if edge is None:
                state[node] = 2
                stack.pop()
                if path:
                    path.pop()
                continue
            if state.get(edge.target) == 1:
                start = next(i for i, step in enumerate(path) if step.source == edge.target) if path else 0
                return [*path[start:], edge]
            if not state.get(edge.target):
                state[edge.target] = 1
                path.append(edge)
                stack.append((edge.target, iter(edges.get(edge.target, []))))
    return None


@pytest.mark.parametrize("rule, importers, forbidden", FORBIDDEN, ids=[rule[0] for rule in FORBIDDEN])
def test_layer_rule(rule: str, importers: tuple[str, ...], forbidden: tuple[str, ...]) -> None:
    broken = [e for e in GRAPH if in_layer(e.source, *importers) and in_layer(e.target, *forbidden)]
    fail_on(broken, rule)


def beyond(target: str, *allowed: str) -> bool:
    """Whether ``target`` is a module of ours outside the ``allowed`` layers."""
    return in_layer(target, "lead_s2r", "lead_s2r_adapters") and not in_layer(target, *allowed)


def test_contracts_import_only_each_other() -> None:
    """schema, geometry and errors import nothing of ours but each other."""
    broken = [e for e in GRAPH if in_layer(e.source, *CONTRACTS) and beyond(e.target, *CONTRACTS)]
    fail_on(broken, "contracts import beyond each other")


def test_formats_import_only_contracts() -> None:
    allowed = (*CONTRACTS, "lead_s2r.formats")
    broken = [e for e in GRAPH if in_layer(e.source, "lead_s2r.formats") and beyond(e.target, *allowed)]
    fail_on(broken, "formats/ import beyond schema, geometry, errors")


def test_pdm_is_plain_numpy_and_shapely() -> None:
    """scoring/pdm/ imports only the contracts, formats and itself of ours, and neither torch nor Lightning (numba,
    which compiles its sequential loops, is a numpy compiler, not a framework)."""
    allowed = (*CONTRACTS, "lead_s2r.formats", "lead_s2r.scoring.pdm")
    pdm = [e for e in GRAPH if in_layer(e.source, "lead_s2r.scoring.pdm")]
    broken = [e for e in pdm if in_layer(e.target, "torch", *LIGHTNING) or beyond(e.target, *allowed)]
    fail_on(broken, "scoring/pdm/ must stay plain numpy/shapely")


def test_nothing_imports_the_orchestrators_or_closed_loop() -> None:
    """closed_loop/ only by cli/ (``lead-s2r closed-loop check``) and itself; demo/ only by cli/ and itself;
    cli/ by nothing."""
    broken = [
        e for e in GRAPH
        if (in_layer(e.target, "lead_s2r.closed_loop")
            and not in_layer(e.source, "lead_s2r.closed_loop", "lead_s2r.cli"))
        or (in_layer(e.target, "lead_s2r.demo") and not in_layer(e.source, "lead_s2r.demo", "lead_s2r.cli"))
        or (in_layer(e.target, "lead_s2r.cli") and not in_layer(e.source, "lead_s2r.cli"))
    ]  # fmt: skip
    fail_on(broken, "only cli/ and demo/ orchestrate; nothing but cli/ imports closed_loop/")


def test_a_hidden_cycle_is_found_and_named(tmp_path: Path) -> None:
    """The checker itself: a cycle through a function-local import is reported with both file:line."""
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "__init__.py").write_text("")
    (tmp_path / "pkg" / "a.py").write_text("from pkg.b import g\n\ndef f():\n    return g()\n")
    (tmp_path / "pkg" / "b.py").write_text("def g():\n    from pkg import a\n    return a\n")
    modules = {"pkg": tmp_path / "pkg" / "__init__.py"}
    modules |= {f"pkg.{name}": tmp_path / "pkg" / f"{name}.py" for name in ("a", "b")}
    edges: dict[str, list[Import]] = {}
    for name, path in modules.items():
        for edge in imports_of(name, path, modules):
            edges.setdefault(edge.source, []).append(edge)
    cycle = find_cycle(edges)
    assert cycle is not None
    assert [(edge.source, edge.target, edge.line) for edge in cycle] == [("pkg.a", "pkg.b", 1), ("pkg.b", "pkg.a", 2)]


#: Layers whose wiring to the other side of a fit is declared (``lead-s2r fit`` links the model and the data module,
#: DESIGN.md §1), and the trainer attributes that would reach around those links.
DECLARED_WIRING = ("data", "training")
REACH_THROUGH = ("datamodule", "lightning_module")


def _is_trainer(node: ast.AST) -> bool:
    """``trainer`` or ``<anything>.trainer``."""
    return (isinstance(node, ast.Name) and node.id == "trainer") or (
        isinstance(node, ast.Attribute) and node.attr == "trainer"
    )


def trainer_reach_through(path: Path) -> list[str]:
    """Every ``trainer.datamodule`` / ``trainer.lightning_module`` in ``path`` (``self.trainer....`` and
    ``getattr(trainer, "...")`` too), as ``file:line``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Attribute) and node.attr in REACH_THROUGH and _is_trainer(node.value):
            found.append(f"{path.name}:{node.lineno}: trainer.{node.attr}")
        elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == "getattr" and len(node.args) >= 2:
            owner, name = node.args[:2]
            if _is_trainer(owner) and isinstance(name, ast.Constant) and name.value in REACH_THROUGH:
                found.append(f"{path.name}:{node.lineno}: getattr(trainer, {name.value!r})")
    return found


def test_data_and_training_never_reach_through_the_trainer() -> None:
    """The model's input spec reaches the data module, and the data module the model, through LightningCLI's
    ``link_arguments`` (lead_s2r/training/cli.py), not by asking the trainer at run time."""
    paths = [path for layer in DECLARED_WIRING for path in sorted((ROOT / "lead_s2r" / layer).rglob("*.py"))]
    assert len(paths) > 20  # the walk sees both layers
    broken = [finding for path in paths for finding in trainer_reach_through(path)]
    if broken:
        pytest.fail("declare the wiring (link_arguments) instead:\n  " + "\n  ".join(broken), pytrace=False)


@pytest.mark.parametrize(
    "planted",
    [
        "def f(self):\n    return self.trainer.datamodule\n",
        "def f(trainer):\n    return trainer.lightning_module.input_spec()\n",
        "def f(self):\n    return getattr(self.trainer, 'lightning_module', None)\n",
    ],
)
def test_a_planted_reach_through_is_caught(tmp_path: Path, planted: str) -> None:
    (tmp_path / "planted.py").write_text(planted)
    assert len(trainer_reach_through(tmp_path / "planted.py")) == 1
    (tmp_path / "clean.py").write_text("def f(self):\n    return self.datamodule, self.trainer.current_epoch\n")
    assert not trainer_reach_through(tmp_path / "clean.py")
