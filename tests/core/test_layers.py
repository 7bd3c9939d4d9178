"""The packages' layers point one way, and no module imports itself back round a cycle.

modsat_core (physics, learning) <- web (what a browser sees; modsat_core's torch-free types
only) <- worker (job store, queue, training processes) <- server (the API and the `modsat`
command line). Inside them, the rooms point one way too (ROOMS): the viewer (web.viewer) below
web's face; the job store (worker.store) below the worker processes; the API's base modules
below its routers, the app and the command line (server.cli). Every import counts, also one
inside a function: a lazy import may keep a command from loading torch, but it may not hide an
upward import or a cycle.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("modsat_core", "web", "worker", "server")
#: What each package may import of the others.
ALLOWED = {
    "modsat_core": set(),
    "web": {"modsat_core"},
    "worker": {"modsat_core", "web"},
    "server": {"modsat_core", "web", "worker"},
}
#: The modsat_core modules web may use: torch-free data types, and the run-folder reader on them.
WEB_MAY_USE = {"modsat_core.grid", "modsat_core.artefacts", "modsat_core.evaluation.run_folder"}
#: modsat_core's own packages, bottom up: each may import the ones before it (and the torch-free
#: top-level modules, `grid` and `artefacts`), never one after it.
CORE_LAYERS = ("spec", "sim", "codesign", "agent", "evaluation", "training", "verify", "bench")
#: The modules at modsat_core's top level: torch-free records every package may use.
CORE_TOP = {"modsat_core", "modsat_core.grid", "modsat_core.artefacts"}
#: The rooms of web, worker and server, bottom up: a module may import its own package's rooms at
#: or below its own, never one above. A room is a module or a sub-package; "*" is the package's
#: other modules (its face, and for server: settings, schemas, deps, submit, security, hosting,
#: service_bench).
ROOMS = {
    "web": ("web.viewer", "*"),
    "worker": ("worker.jsonsafe", "worker.store", "*"),
    "server": ("*", "server.routers", "server.app", "server.cli"),
}


def module_imports(root: Path) -> dict[str, set[str]]:
    """Every module of PACKAGES under ``root`` -> the project modules it imports (anywhere in it)."""
    graph: dict[str, set[str]] = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            rel = path.relative_to(root).with_suffix("")
            name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
            package = name if rel.name == "__init__" else name.rpartition(".")[0]
            found: set[str] = set()
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    found.update(a.name for a in node.names)
                elif isinstance(node, ast.ImportFrom):
                    if node.level:
                        base = package.split(".")
                        base = base[: len(base) - node.level + 1]
                        mod = ".".join(base + ([node.module] if node.module else []))
                    else:
                        mod = node.module or ""
                    found.add(mod)
                    # `from . import dynamics` names a module, not an attribute
                    found.update(f"{mod}.{a.name}" for a in node.names)
            graph[name] = {m for m in found if m.split(".")[0] in PACKAGES}
    modules = set(graph)
    # keep the names that are modules (`from .x import f` also added `pkg.x.f`)
    return {k: {m for m in v if m in modules and m != k} for k, v in graph.items()}


def layer_violations(graph: dict[str, set[str]]) -> list[str]:
    out = []
    for mod, deps in sorted(graph.items()):
        pkg = mod.split(".")[0]
        for dep in sorted(deps):
            dpkg = dep.split(".")[0]
            if dpkg != pkg and dpkg not in ALLOWED[pkg]:
                out.append(f"{mod} imports {dep}: {pkg} may not import {dpkg}")
            if pkg == "web" and dpkg == "modsat_core" and dep not in WEB_MAY_USE:
                out.append(f"{mod} imports {dep}: web uses only modsat_core's torch-free types {sorted(WEB_MAY_USE)}")
    return out


def core_layer(mod: str) -> int:
    """The layer of a modsat_core module: -1 for the top-level modules, else CORE_LAYERS' index."""
    if mod in CORE_TOP:
        return -1
    return CORE_LAYERS.index(mod.split(".")[1])


def core_layer_violations(graph: dict[str, set[str]]) -> list[str]:
    out = []
    for mod, deps in sorted(graph.items()):
        if not mod.startswith("modsat_core"):
            continue
        for dep in sorted(d for d in deps if d.startswith("modsat_core")):
            if mod == "modsat_core":  # the package's face: it registers the env and re-exports the spec
                continue
            if mod in CORE_TOP and dep not in CORE_TOP:
                out.append(f"{mod} imports {dep}: modsat_core's top-level modules import no package of it")
            elif core_layer(dep) > core_layer(mod):
                out.append(
                    f"{mod} imports {dep}: {CORE_LAYERS[core_layer(dep)]} is above {CORE_LAYERS[core_layer(mod)]}"
                )
    return out


def room(mod: str) -> tuple[str, int]:
    """A module of web, worker or server -> (its room, the room's index in ROOMS)."""
    rooms = ROOMS[mod.split(".")[0]]
    for i, r in enumerate(rooms):
        if r != "*" and (mod == r or mod.startswith(r + ".")):
            return r, i
    return "*", rooms.index("*")


def room_violations(graph: dict[str, set[str]]) -> list[str]:
    out = []
    for mod, deps in sorted(graph.items()):
        pkg = mod.split(".")[0]
        if pkg not in ROOMS:
            continue
        name, level = room(mod)
        for dep in sorted(d for d in deps if d.split(".")[0] == pkg):
            dep_name, dep_level = room(dep)
            if dep_level > level:
                out.append(f"{mod} imports {dep}: {pkg}'s room {dep_name} is above {name}")
    return out


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles (each as the path that closes it), by depth-first search."""
    found, state, stack = [], {}, []

    def visit(m: str) -> None:
        state[m] = "open"
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            # a package's __init__ is imported by its own modules' imports; a module
            # importing its package's __init__ is not a cycle by itself
            if state.get(d) == "open":
                found.append([*stack[stack.index(d) :], d])
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = "done"

    for m in sorted(graph):
        if m not in state:
            visit(m)
    return found


def test_layers_point_one_way():
    assert layer_violations(module_imports(ROOT)) == []


def test_modsat_core_packages_point_one_way():
    graph = module_imports(ROOT)
    assert {m.split(".")[1] for m in graph if m.startswith("modsat_core.") and m not in CORE_TOP} == set(CORE_LAYERS)
    assert core_layer_violations(graph) == []


def test_the_rooms_inside_web_worker_and_server_point_one_way():
    graph = module_imports(ROOT)
    for pkg, rooms in ROOMS.items():  # every room named is there
        for r in rooms:
            assert r == "*" or r in graph, f"{r} (ROOMS[{pkg!r}]) is not a module or package"
    assert room_violations(graph) == []


def test_no_import_cycles():
    assert cycles(module_imports(ROOT)) == []


def test_the_check_fails_on_a_planted_upward_import_and_cycle(tmp_path):
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "modsat_core" / "low.py").write_text("def f():\n    from server import app  # upward\n")
    (tmp_path / "server" / "app.py").write_text("from modsat_core import low\n")
    (tmp_path / "worker" / "a.py").write_text("from .b import x\n")
    (tmp_path / "worker" / "b.py").write_text("def g():\n    from worker.a import y\n")
    (tmp_path / "web" / "scene.py").write_text("from modsat_core.low import f\n")
    (tmp_path / "worker" / "store").mkdir()
    (tmp_path / "worker" / "store" / "__init__.py").write_text("")
    (tmp_path / "worker" / "store" / "queue.py").write_text("def h():\n    from worker.main import run  # upward\n")
    (tmp_path / "worker" / "main.py").write_text("from .store import queue\n")
    graph = module_imports(tmp_path)
    rooms = room_violations(graph)
    assert any(p.startswith("worker.store.queue imports worker.main") for p in rooms), rooms
    assert not any(p.startswith("worker.main") for p in rooms), rooms
    problems = layer_violations(graph)
    assert any(p.startswith("modsat_core.low imports server.app") for p in problems), problems
    assert any(p.startswith("web.scene imports modsat_core.low") for p in problems), problems
    for sub in ("sim", "spec"):
        (tmp_path / "modsat_core" / sub).mkdir()
        (tmp_path / "modsat_core" / sub / "__init__.py").write_text("")
    (tmp_path / "modsat_core" / "spec" / "doc.py").write_text("from modsat_core.sim.slew import SlewSim\n")
    (tmp_path / "modsat_core" / "sim" / "slew.py").write_text("")
    core_problems = core_layer_violations(module_imports(tmp_path))
    assert any(p.startswith("modsat_core.spec.doc imports modsat_core.sim.slew") for p in core_problems), core_problems
    found = cycles(graph)
    assert ["worker.a", "worker.b", "worker.a"] in found, found
    assert any("modsat_core.low" in c and "server.app" in c for c in found), found


def test_the_api_and_the_command_line_load_no_torch():
    code = "import sys\nimport server.app, server.cli\nassert 'torch' not in sys.modules, 'torch was imported'\n"
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


def test_validating_a_spec_and_drawing_the_scene_load_no_torch():
    code = (
        "import sys\n"
        "import modsat_core.spec.jobspec as s\n"
        "import web.viewer.scene, web.viewer.run, web.viewer.recording\n"
        "grid = [[[0, 0], [0, 0]], [[1, 2], [0, 0]]]\n"
        "spec = s.parse_spec({'algorithm': 'td3-control', 'design': {'grid_size': 2, 'fixed_design': grid}})\n"
        "assert spec.design.fixed_design == grid\n"
        "try:\n"
        "    s.parse_spec({'algorithm': 'td3-control', 'design': {'grid_size': 2, 'fixed_design': "
        "[[[1, 0], [0, 0]], [[0, 0], [0, 1]]]}})\n"
        "    raise SystemExit('an invalid design was accepted')\n"
        "except s.SpecError as exc:\n"
        "    assert 'not a valid satellite' in str(exc), exc\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
