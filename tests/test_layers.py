"""The package's layers import downward only, with no cycles (physics → models → training → data → core → latent
→ tasks → sim / lfd / deploy → cli / reproduce / view), and no module imports another module's private names.
A built-in task's folder (``tasks/<name>/``) is a vertical slice: each of its files sits in the layer of its role."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "src" / "seqmotion"
RANK = {"errors": 0, "io": 0, "physics": 1, "models": 2, "training": 3, "data": 4, "core": 5, "latent": 6, "tasks": 7,
        "api": 7, "sim": 8, "lfd": 8, "deploy": 8, "cli": 9, "reproduce": 9, "view": 9}
"""physics → models → training → data → core (the task contract, results, trained model, stepper) → latent (the
optimiser on trained models, for any task) → tasks (one module or folder per task; their own objectives on the
optimiser) → sim / lfd / deploy → cli / reproduce / view (docs/architecture.md)."""
ROLE_RANK = {"physics": RANK["physics"], "data": RANK["data"], "task": RANK["tasks"], "robot": RANK["tasks"],
             "latent": RANK["tasks"], "sim": RANK["sim"]}
"""The rank of a file in a task's folder, ``tasks/<name>/<role>.py``, by its name: ``physics`` 1 (the task's dynamics
and constraint), ``data`` 4 (its input generators), ``task``, ``robot`` (the plan on a robot: its limits as objective
terms, which the planner keeps), ``latent`` (the task's own objectives and refinements, on the latent optimiser one
rank below) and the folder's ``__init__``: the task's rank, 7 (what the registry imports); ``sim`` 8 (MuJoCo). A file
of any other name takes the task's rank."""


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(module: str) -> int | None:
    parts = module.split(".")
    if len(parts) < 2:
        return None  # the package root re-exports the public API
    if parts[-1] == "cli":  # each subsystem's command-line module is entry-point code
        return RANK["cli"]
    if parts[1] == "tasks" and len(parts) > 3:  # seqmotion.tasks.<name>.<role>[...]: the rank of the role
        return ROLE_RANK.get(parts[3], RANK["tasks"])
    return RANK.get(parts[1])


def import_layer(source: str, target: str) -> int | None:
    """The highest rank that importing module ``target`` from ``source`` runs: the target's, and that of each package
    above it that ``source`` is not inside already. Importing ``seqmotion.tasks.sliding.physics`` (rank 1) from
    ``data/`` runs ``tasks/__init__`` and ``tasks/sliding/__init__`` (rank 6: they import the task) first; from
    ``tasks/sliding/data.py`` it runs neither anew."""
    parts, own = target.split("."), source.split(".")
    ranks = [layer(".".join(parts[:i])) for i in range(2, len(parts) + 1) if own[:i] != parts[:i]]
    return max((r for r in ranks if r is not None), default=None)


def subsystem(module: str) -> list[str]:
    """What may share private names: a top-level package of ``seqmotion``, or one task's folder."""
    parts = module.split(".")
    return parts[:3] if parts[1:2] == ["tasks"] else parts[:2]


MODULES = {module_name(p) for p in ROOT.rglob("*.py")}


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


def targets(target: str, names: list[str]) -> list[str]:
    """The modules ``from target import names`` imports: each name that is a module of its own (``from . import
    physics``), else ``target`` itself."""
    found = [f"{target}.{n}" for n in names if f"{target}.{n}" in MODULES]
    return found + ([target] if len(found) < len(names) or not names else [])


def test_layers_import_downward_only_and_no_private_names():
    upward, private = [], []
    for path in ROOT.rglob("*.py"):
        source = module_name(path)
        for target, names in imports(path):
            for module in targets(target, names):
                a, b = layer(source), import_layer(source, module)
                if a is not None and b is not None and b > a:
                    upward.append(f"{source} → {module}")
            if subsystem(target) != subsystem(source):  # across subsystems: public names only
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


def test_a_task_folder_is_ranked_by_role_and_its_parents_count():
    """The role ranks catch a task's file importing above its role, and a lower layer reaching into a task's folder
    (which runs the folder's ``__init__``, the task)."""
    assert [layer(f"seqmotion.tasks.sliding.{role}") for role in ("physics", "data", "task", "robot", "latent")] == [
        1, 4, 7, 7, 7]
    assert layer("seqmotion.tasks.sliding") == layer("seqmotion.tasks") == 7
    assert layer("seqmotion.latent.optimize") == 6  # below the tasks: a task builds its objectives on it
    assert import_layer("seqmotion.tasks.sliding.physics", "seqmotion.core.task") == 5  # physics → core: upward
    assert import_layer("seqmotion.tasks.sliding.data", "seqmotion.tasks.sliding.physics") == 1  # within the folder
    assert import_layer("seqmotion.tasks.sliding.physics", "seqmotion.tasks.sliding.task") == 7  # upward
    assert import_layer("seqmotion.data.trajectories", "seqmotion.tasks.sliding.physics") == 7  # runs the task
    assert import_layer("seqmotion.sim.envs", "seqmotion.tasks.sliding.physics") == 7  # from above: fine
    assert targets("seqmotion.tasks.sliding", ["physics", "SlidingTask"]) == [
        "seqmotion.tasks.sliding.physics", "seqmotion.tasks.sliding"]
    assert subsystem("seqmotion.tasks.pancake.latent") != subsystem("seqmotion.tasks.sliding.latent")
