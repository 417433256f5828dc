"""The import arrows of the repository (docs/ARCHITECTURE.md): cli -> studies -> sweep -> run ->
modes -> dem, never backwards, and no import circle anywhere (function-level imports included).
Read from the source with ast: nothing is imported."""
import ast
import os

from tests.helpers import ROOT

# layer of each package prefix, lowest first; a module may import only its own layer or lower ones
LAYERS = ["dem", "modes", "bench.run", "bench.sweep", "bench.studies", "bench.cli"]


def modules():
    """{module name: path} of every .py file of dem/, modes/ and bench/."""
    out = {}
    for pkg in ("dem", "modes", "bench"):
        for folder, _, files in os.walk(os.path.join(ROOT, pkg)):
            for f in files:
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(folder, f), ROOT)[:-3].replace(os.sep, ".")
                    out[rel[:-len(".__init__")] if rel.endswith(".__init__") else rel] = os.path.join(folder, f)
    return out


def imports(path, known):
    """Project modules named by the import statements of a file (anywhere in it): `from p import
    m` names module p.m where that is a module of `known`, else p."""
    names = set()
    for node in ast.walk(ast.parse(open(path).read())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                names.add(sub if sub in known else node.module)
    return {n for n in names if n.split(".")[0] in ("dem", "modes", "bench")}


def layer(module):
    best = None
    for k, prefix in enumerate(LAYERS):
        if module == prefix or module.startswith(prefix + "."):
            best = k
    return best


def graph():
    mods = modules()
    return {m: {i for i in imports(p, mods) if i in mods and i != m} for m, p in mods.items()}


def test_arrows_point_down():
    """No module imports a layer above its own (bench/__init__ and __main__ sit on top)."""
    wrong = []
    for m, deps in graph().items():
        lm = layer(m)
        if lm is None:  # bench, bench.__main__: the package's entry points
            continue
        for d in deps:
            ld = layer(d)
            if ld is not None and ld > lm:
                wrong.append(f"{m} -> {d}")
    assert wrong == []


def test_dem_imports_no_modes_bench_or_mpi():
    """dem/ is physics only (DESIGN.md): no modes, bench or mpi4py import anywhere in it."""
    bad = []
    for m, p in modules().items():
        if m.split(".")[0] == "dem":
            src = open(p).read()
            names = {n for n in imports(p, ()) if n.split(".")[0] in ("modes", "bench")}
            if names or "mpi4py" in {getattr(a, "name", "") for node in ast.walk(ast.parse(src))
                                     if isinstance(node, ast.Import) for a in node.names}:
                bad.append(m)
    assert bad == []


def test_no_import_circle():
    """Depth-first search over the module graph finds no cycle (the issue counted three)."""
    g = graph()
    state, cycles = {}, []

    def visit(m, stack):
        state[m] = 1
        for d in sorted(g[m]):
            if state.get(d) == 1:
                cycles.append(" -> ".join(stack[stack.index(d):] + [d]))
            elif d not in state:
                visit(d, stack + [d])
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m, [m])
    assert cycles == []
