"""Code-shape counts of issue 40, by an ast scan of the packages (no imports, no execution).

- public functions returning a dict: a public function (name without a leading underscore, its class
  public too) with a ``dict`` return annotation or a ``return`` of a dict literal, comprehension or
  ``dict(...)`` call (its own returns, not those of functions defined inside it);
- ``["key"]`` lookups: subscripts whose index is a string constant, per 1,000 lines;
- functions with more than 6 positional parameters (``self``/``cls`` not counted);
- command bodies: the line count of each click command's function body (decorated ``@click.command``,
  ``@<group>.command`` or ``cls=Command``), longest first;
- README lines; committed result files (PNG/JSON under ``results/`` or ``bench/results/``);
- import cycles: strongly connected components of more than one module in the graph of the modules'
  imports (lazy imports inside functions included; ``from p import m`` counts as importing module
  ``p.m`` when that is a module, else ``p``), the cycle count ``lint-imports`` keeps at 0 per package.

    python bench/code_metrics.py [--json OUT.json] [--top N]
"""

from __future__ import annotations

import argparse
import ast
import json
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("aerotri", "lidarctl", "ortho")


def _own_nodes(fn: ast.FunctionDef):
    """The nodes of ``fn``'s body, not those of the functions and lambdas defined inside it (a nested helper's
    ``return {...}`` is not ``fn``'s return)."""
    todo = list(fn.body)
    while todo:
        node = todo.pop()
        yield node
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            todo.extend(ast.iter_child_nodes(node))


def _returns_dict(fn: ast.FunctionDef) -> bool:
    ann = fn.returns
    if ann is not None:
        text = ast.unparse(ann)
        if text == "dict" or text.startswith("dict[") or text.startswith("Dict"):
            return True
    for node in _own_nodes(fn):
        if isinstance(node, ast.Return) and node.value is not None:
            v = node.value
            if isinstance(v, (ast.Dict, ast.DictComp)):
                return True
            if isinstance(v, ast.Call) and isinstance(v.func, ast.Name) and v.func.id == "dict":
                return True
    return False


def _is_command(fn: ast.FunctionDef) -> bool:
    for d in fn.decorator_list:
        call = d if isinstance(d, ast.Call) else None
        target = call.func if call else d
        name = ast.unparse(target)
        if name.endswith(".command") or name.endswith(".group"):
            return True
        if call and any(k.arg == "cls" and ast.unparse(k.value) in ("Command", "Group") for k in call.keywords):
            return True
    return False


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_cycles(root: Path = ROOT) -> list:
    """The import cycles of the packages: lists of module names (each a strongly connected component of
    two or more modules), by Tarjan's algorithm over the import graph."""
    paths = {_module_name(root, p): p for pkg in PACKAGES for p in sorted((root / pkg).rglob("*.py"))}
    graph = {}
    for mod, path in paths.items():
        is_pkg = path.name == "__init__.py"
        edges = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                edges.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from the module's package, one level up per extra dot
                    pkg = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    pkg = pkg[:len(pkg) - node.level + 1]
                    base = ".".join(pkg + ([base] if base else []))
                for a in node.names:
                    edges.add(f"{base}.{a.name}" if f"{base}.{a.name}" in paths else base)
        graph[mod] = sorted(e for e in edges if e in paths and e != mod)
    index, low, on_stack, stack, sccs = {}, {}, set(), [], []
    for start in graph:  # iterative Tarjan (no recursion limit on long import chains)
        if start in index:
            continue
        work = [(start, iter(graph[start]))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(graph[w])))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    sccs.append(sorted(comp))
    return sorted(sccs)


def scan(root: Path = ROOT) -> dict:
    dict_returns, many_args, commands = [], [], []
    key_lookups = lines = 0
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            src = path.read_text()
            lines += src.count("\n")
            tree = ast.parse(src)
            rel = str(path.relative_to(root))
            for node in ast.walk(tree):
                if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant) \
                        and isinstance(node.slice.value, str):
                    key_lookups += 1
            # functions with their enclosing class (public = neither is private)
            stack = [(tree, True)]
            while stack:
                parent, public = stack.pop()
                for node in ast.iter_child_nodes(parent):
                    if isinstance(node, ast.ClassDef):
                        stack.append((node, public and not node.name.startswith("_")))
                    elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                        name = f"{rel}:{node.name}"
                        pos = [a.arg for a in node.args.posonlyargs + node.args.args if a.arg not in ("self", "cls")]
                        if len(pos) > 6:
                            many_args.append((name, len(pos)))
                        if public and not node.name.startswith("_") and _returns_dict(node):
                            dict_returns.append(name)
                        if _is_command(node):
                            body = node.body
                            # the docstring is not body
                            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                                body = body[1:]
                            n = (body[-1].end_lineno - body[0].lineno + 1) if body else 0
                            commands.append((name, n))
    readme = (root / "README.md").read_text().count("\n") if (root / "README.md").exists() else 0
    try:
        tracked = subprocess.run(["git", "ls-files"], cwd=root, capture_output=True, text=True, check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        tracked = []
    results = [t for t in tracked if t.split("/")[0] in ("results",) or t.startswith("bench/results/")]
    results = [t for t in results if t.endswith((".png", ".json", ".jpg"))]
    commands.sort(key=lambda c: -c[1])
    cycles = import_cycles(root)
    return {
        "lines": lines,
        "public_dict_returns": len(dict_returns),
        "public_dict_returns_per_kloc": round(1000 * len(dict_returns) / max(lines, 1), 2),
        "key_lookups_per_kloc": round(1000 * key_lookups / max(lines, 1), 1),
        "functions_over_6_positional": len(many_args),
        "longest_command_body_lines": commands[0][1] if commands else 0,
        "commands_over_15_lines": sum(1 for _, n in commands if n > 15),
        "readme_lines": readme,
        "committed_result_files": len(results),
        "import_cycles": len(cycles),
        "dict_returns": dict_returns,
        "many_positional": sorted(many_args, key=lambda a: -a[1]),
        "command_bodies": commands,
        "import_cycle_modules": cycles,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--top", type=int, default=10)
    a = ap.parse_args()
    m = scan()
    for k, v in m.items():
        if not isinstance(v, list):
            print(f"{k:36s} {v}")
    print(f"\nlongest command bodies (top {a.top}):")
    for name, n in m["command_bodies"][:a.top]:
        print(f"  {n:4d}  {name}")
    for comp in m["import_cycle_modules"]:
        print("import cycle: " + " <-> ".join(comp))
    if a.json:
        a.json.write_text(json.dumps(m, indent=1) + "\n")


if __name__ == "__main__":
    main()
