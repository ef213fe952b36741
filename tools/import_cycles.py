"""Import cycles among clisp's modules (issue 26): every clisp import, at module level and inside
functions, as a graph; prints its strongly connected components of more than one module.

    python tools/import_cycles.py [REPO]      # exit 1 when there is a cycle

``from . import name`` counts as an import of the package's ``__init__`` unless ``name`` is a
submodule (importing a submodule needs no name the package defines).
"""
import ast
import sys
from pathlib import Path

root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1]) / "clisp"
mods = {}
for f in root.rglob("*.py"):
    name = ".".join(f.relative_to(root.parent).with_suffix("").parts)
    if name.endswith(".__init__"): name = name[:-9]
    mods[name] = f
graph = {m: set() for m in mods}
for m, f in mods.items():
    pkg = m if f.name == "__init__.py" else m.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(f.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[:len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            subs = [f"{target}.{a.name}" for a in node.names]
            cands = [c for c in subs if c in mods] + ([target] if any(c not in mods for c in subs) else [])
        elif isinstance(node, ast.Import):
            cands = [a.name for a in node.names]
        else:
            continue
        for c in cands:
            if c in mods and c != m:
                graph[m].add(c)
# strongly connected components (Tarjan)
idx, low, st, on, out, n = {}, {}, [], set(), [], [0]
def sc(v):
    idx[v] = low[v] = n[0]; n[0] += 1; st.append(v); on.add(v)
    for w in graph[v]:
        if w not in idx: sc(w); low[v] = min(low[v], low[w])
        elif w in on: low[v] = min(low[v], idx[w])
    if low[v] == idx[v]:
        comp = []
        while True:
            w = st.pop(); on.discard(w); comp.append(w)
            if w == v: break
        if len(comp) > 1: out.append(sorted(comp))
sys.setrecursionlimit(10000)
for v in graph:
    if v not in idx: sc(v)
print("cycles:", out if out else "none")
sys.exit(1 if out else 0)
