"""The package's layers import downward only, with no cycles (physics → models → training → data → core →
tasks → latent / sim / lfd / deploy → cli / reproduce / view), and no module imports another module's private names."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "src" / "seqmotion"
RANK = {"errors": 0, "io": 0, "physics": 1, "models": 2, "training": 3, "data": 4, "core": 5, "tasks": 6, "api": 6,
        "latent": 7, "sim": 7, "lfd": 7, "deploy": 7, "cli": 8, "reproduce": 8, "view": 8}
"""physics → models → training → data → core (the task contract, results, trained model, stepper) → tasks
(one module or folder per task) → latent / sim / lfd / deploy → cli / reproduce / view (docs/architecture.md)."""


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(module: str) -> int | None:
    parts = module.split(".")
    if len(parts) < 2:
        return None  # the package root re-exports the public API
    if parts[-1] == "cli":  # each subsystem's command-line module is entry-point code
        return RANK["cli"]
    return RANK.get(parts[1])


def imports(path: Path) -> list[tuple[str, list[str]]]:
    """Every ``seqmotion`` module ``path`` imports (at any depth of the file), with the names taken from it."""
    here = module_name(path).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            target = ".".join(base + ([node.module] if node.module else []))
            if target.startswith("seqmotion"):
                found.append((target, [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            found += [(a.name, []) for a in node.names if a.name.startswith("seqmotion")]
    return found


def test_layers_import_downward_only_and_no_private_names():
    upward, private = [], []
    for path in ROOT.rglob("*.py"):
        source = module_name(path)
        for target, names in imports(path):
            a, b = layer(source), layer(target)
            if a is not None and b is not None and b > a:
                upward.append(f"{source} → {target}")
            if target.split(".")[:2] != source.split(".")[:2]:  # across subsystems: public names only
                private += [f"{source} → {target}.{n}" for n in names if n.startswith("_") and n != "__version__"]
    assert not upward, "upward imports:\n" + "\n".join(sorted(upward))
    assert not private, "private names imported across subsystems:\n" + "\n".join(sorted(private))


def test_no_import_cycles_between_modules():
    graph: dict[str, set[str]] = {}
    modules = {module_name(p) for p in ROOT.rglob("*.py")}
    for path in ROOT.rglob("*.py"):
        edges = set()
        for target, names in imports(path):
            for candidate in [f"{target}.{n}" for n in names] + [target]:
                if candidate in modules:
                    edges.add(candidate)
                    break
        graph[module_name(path)] = edges - {module_name(path)}
    # packages import their own submodules from __init__; an edge package → its own child is not a cycle
    seen, stack, cycles = set(), [], []

    def visit(node: str) -> None:
        stack.append(node)
        for nxt in graph.get(node, ()):
            if nxt in stack:
                cycle = stack[stack.index(nxt):] + [nxt]
                pairs = zip(cycle, cycle[1:], strict=False)
                if not all(b.startswith(a + ".") or a.startswith(b + ".") for a, b in pairs):
                    cycles.append(" → ".join(cycle))
            elif nxt not in seen:
                visit(nxt)
        stack.pop()
        seen.add(node)

    for module in sorted(graph):
        if module not in seen:
            visit(module)
    assert not cycles, "import cycles:\n" + "\n".join(cycles)
