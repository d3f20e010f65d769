"""The folders show the architecture: every `alight.*` import in systems/, diagrams/ and hw/
(function-local ones included) follows the layering of README.md's Layout, and no import cycle."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASE = ("alight.diagrams.running.paths", "alight.diagrams.running.simulation",
        "alight.diagrams.running.run_log")
LOW = ("alight.systems", "alight.models")
# importer (the longest matching prefix wins) -> the prefixes it may import, besides its package
RULES = {
    "alight": (),
    "alight.systems": LOW,
    "alight.diagrams.world": LOW,
    **{base: (*LOW, "alight.diagrams.world.visualization", *BASE) for base in BASE},
    "alight.diagrams.onboard": (*LOW, *BASE),
    "alight.diagrams.analysis": (*LOW, "alight.diagrams.running.run_log", "alight.hw.ulog",
                                 "alight.hw.frames"),
    "alight.diagrams.scenario": (*LOW, "alight.diagrams.world", "alight.diagrams.onboard"),
    "alight.diagrams.stacks": (*LOW, "alight.diagrams.onboard", "alight.diagrams.scenario",
                               *BASE),
    "alight.hw": (*LOW, "alight.hw", "alight.diagrams.world", "alight.diagrams.onboard",
                  "alight.diagrams.scenario", "alight.diagrams.stacks", *BASE),
    "alight.diagrams.running": (*LOW, "alight.hw", "alight.diagrams.world",
                                "alight.diagrams.onboard", "alight.diagrams.scenario",
                                "alight.diagrams.stacks", "alight.diagrams.running",
                                "alight.diagrams.analysis"),
    "alight.diagrams.cli": ("alight",),
}


def _modules() -> dict[str, Path]:
    return {".".join(("alight", *path.relative_to(ROOT).with_suffix("").parts))
            .removesuffix(".__init__"): path
            for folder in ("systems", "diagrams", "hw") for path in (ROOT / folder).rglob("*.py")}


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets |= {a.name for a in node.names if a.name.startswith("alight.")}
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("alight."):
                targets |= {f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules
                            else node.module for a in node.names}
        graph[name] = targets - {name}
    return graph


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def _package(name: str) -> str:
    return name if _modules()[name].name == "__init__.py" else name.rpartition(".")[0]


def test_every_import_follows_the_layering():
    broken = []
    for importer, targets in _graph().items():
        rule = max((p for p in RULES if _within(importer, p)), key=len)
        broken += [f"{importer} -> {t}" for t in sorted(targets)
                   if not any(_within(t, p) for p in RULES[rule])
                   and t.rpartition(".")[0] != _package(importer) and t != _package(importer)]
    assert not broken, "imports against the layering:\n" + "\n".join(broken)


def test_the_module_import_graph_has_no_cycle():
    graph, done, path = _graph(), set(), []

    def visit(name):
        if name in path:
            raise AssertionError("import cycle: " + " -> ".join(path[path.index(name):] + [name]))
        if name in done or name not in graph:
            return
        path.append(name)
        for target in sorted(graph[name]):
            visit(target)
        path.pop()
        done.add(name)

    for name in sorted(graph):
        visit(name)
