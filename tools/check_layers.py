#!/usr/bin/env python3
"""Check that hallray's imports follow its layers (docs/architecture.md); run by CI.

Fails (exit 1, one line per violation) on:

* an import that goes against the arrows between raytrace's subpackages (``LAYERS`` below) or
  between positioning's (``POSITIONING_LAYERS``);
* ``positioning`` importing ``raytrace``, or anything importing ``raytrace.cli``;
* ``hallray`` (the commands' shared infrastructure) importing ``raytrace`` or ``positioning``
  (only its future console command, ``hallray.main`` / ``hallray.cli``, may; nothing imports
  that);
* a raytrace layer below ``studies`` importing ``positioning``, or any module importing an old
  (deprecated) path of positioning: a top-level module of it other than the package itself
  and ``positioning.errors``;
* a solver stage module imported by anything but the tracer;
* an import cycle between our modules (module-level and function-local imports together);
* a function-local import of our own module that would close a cycle if it were at module level
  (an import made only to dodge a cycle).

Function-local imports that do not close a cycle are fine (lazy loading of heavy modules).
Imports inside ``if TYPE_CHECKING:`` count like any other: a cycle of types is a cycle. Standard
library only.

Usage: ``python tools/check_layers.py [ROOT]`` (default: the checkout this file is in).
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

# the tools' harness (one-line errors, exit status 2 on bad input): standard library only
from hallray.harness import OneLineParser, run_command  # noqa: E402

#: Our packages, checked together (an import between them counts like one within).
PACKAGES = ("raytrace", "positioning", "hallray")


class LayerCheckError(Exception):
    """Bad input to this tool (a ROOT that is not a checkout): one line, exit status 2."""


#: Subpackage -> the subpackages of raytrace it may import (itself included).
LAYERS: dict[str, set[str]] = {
    "core": {"core"},
    "physics": {"core", "physics"},
    "scene": {"core", "physics", "scene"},
    "solver": {"core", "physics", "scene", "solver"},
    "emulation": {"core", "physics", "scene", "solver", "emulation"},
    "halls": {"core", "physics", "scene", "halls"},
    "viz": {"core", "physics", "scene", "solver.paths", "halls", "viz"},
    "studies": {"core", "physics", "scene", "solver", "emulation", "halls", "viz", "studies"},
    "cli": {"core", "physics", "scene", "solver", "emulation", "halls", "viz", "studies", "cli"},
}
#: The package's own __init__ re-exports the public API from these.
TOP_ALLOWED = {"core", "physics", "scene", "solver", "emulation"}
#: The raytrace layers that may import positioning (its public API and its subpackages).
USES_POSITIONING = {"studies", "cli"}

#: Subpackage of positioning -> the subpackages of positioning it may import (itself included),
#: along the flow ToA -> problem -> estimate -> evaluate -> report. Every module may also import
#: ``positioning.errors``; positioning's top-level modules (the lazy public API in ``__init__``,
#: the old paths' shims) may import any of it.
POSITIONING_LAYERS: dict[str, set[str]] = {
    "model": {"model"},
    "io": {"model", "io"},
    "estimators": {"model", "estimators"},
    "twin": {"model", "estimators", "twin"},
    "evaluation": {"model", "estimators", "evaluation"},
    "methods": {"model", "estimators", "twin", "evaluation", "methods"},
    "report": {"model", "io", "estimators", "twin", "evaluation", "methods", "report"},
    "cli": {"model", "io", "estimators", "twin", "evaluation", "methods", "report", "cli"},
}
#: Top-level modules of positioning that are not old paths: the public API and the error type.
POSITIONING_CURRENT = {"positioning", "positioning.errors"}
#: The one-release forwarding helper of the old paths (imported by the shims only).
POSITIONING_SHIM_HELPER = "positioning.deprecated"
#: Modules of hallray that may import the two packages (the future ``hallray`` console command).
HALLRAY_COMMAND = ("hallray.main", "hallray.cli")
#: Solver modules that only the tracer may import (the stages and their back end).
STAGES = {"raytrace.solver.specular", "raytrace.solver.diffraction", "raytrace.solver.evaluate"}
STAGE_IMPORTERS = {"raytrace.solver.tracer"} | STAGES


def module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports_of(tree: ast.Module, mod: str, is_pkg: bool, known: set[str]):
    """Yield ``(target module, line, local)`` for every import of our own modules."""

    def resolve(node: ast.ImportFrom) -> list[str]:
        if node.level:
            base = mod.split(".") if is_pkg else mod.split(".")[:-1]
            base = base[: len(base) - (node.level - 1)]
            prefix = ".".join(base + ([node.module] if node.module else []))
        else:
            prefix = node.module or ""
        out = []
        for alias in node.names:
            sub = f"{prefix}.{alias.name}"
            out.append(sub if sub in known else prefix)
        return out

    def visit(node: ast.AST, local: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = local or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                for a in child.names:
                    found.append((a.name, child.lineno, local))
            elif isinstance(child, ast.ImportFrom):
                for target in resolve(child):
                    found.append((target, child.lineno, local))
            visit(child, inner)

    found: list[tuple[str, int, bool]] = []
    visit(tree, False)
    for target, line, local in found:
        while target and target not in known:
            target = target.rpartition(".")[0]
        if target:
            yield target, line, local


def layer_of(mod: str) -> str | None:
    parts = mod.split(".")
    if parts[0] != "raytrace":
        return None
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else ""


def in_package(mod: str, pkg: str) -> bool:
    """Whether ``mod`` is the module or package ``pkg`` or inside it."""
    return mod == pkg or mod.startswith(f"{pkg}.")


def positioning_layer(mod: str) -> str:
    """The subpackage of positioning that ``mod`` is in ("" for a top-level module)."""
    parts = mod.split(".")
    inside = len(parts) > 2 or (len(parts) == 2 and parts[1] in POSITIONING_LAYERS)
    return parts[1] if inside else ""


def allowed_hallray(src: str, dst: str) -> bool | None:
    """The rules of hallray's imports and of imports of hallray (None: not concerned)."""
    if any(in_package(dst, c) for c in HALLRAY_COMMAND):
        return any(in_package(src, c) for c in HALLRAY_COMMAND)  # nothing imports the command
    if in_package(src, "hallray") and not any(in_package(src, c) for c in HALLRAY_COMMAND):
        return not (in_package(dst, "raytrace") or in_package(dst, "positioning"))
    if in_package(dst, "hallray"):
        return True  # the commands' infrastructure is below every layer of both packages
    return None


def allowed_positioning(src: str, dst: str) -> bool | None:
    """The rules of positioning's imports and of imports of positioning (None: not concerned)."""
    if not in_package(dst, "positioning"):
        return False if in_package(src, "positioning") and in_package(dst, "raytrace") else None
    d = positioning_layer(dst)
    if d == "" and dst not in POSITIONING_CURRENT:
        # an old path (a shim forwarding for one release) or the shims' helper
        return dst == POSITIONING_SHIM_HELPER and src.count(".") == 1
    if in_package(src, "raytrace"):
        return layer_of(src) in USES_POSITIONING
    if not in_package(src, "positioning"):
        return None
    s = positioning_layer(src)
    if s == "" or dst == "positioning.errors":
        return True  # the lazy public API, the shims; the error type for all
    if d == "":
        return False  # the package's public API is for its users, not its layers
    return d in POSITIONING_LAYERS[s]


def allowed(src: str, dst: str) -> bool:
    for rule in (allowed_hallray, allowed_positioning):
        verdict = rule(src, dst)
        if verdict is not None:
            return verdict
    s, d = layer_of(src), layer_of(dst)
    if s is None or d is None:
        return True  # positioning targets are checked by the raytrace side below
    if d == "":  # raytrace/__init__ (the public API, __version__)
        return s == ""
    if s == "":
        return d in TOP_ALLOWED
    if d == "cli":
        return s == "cli"
    if dst in STAGES and src not in STAGE_IMPORTERS:
        return False
    ok = LAYERS[s]
    if d in ok:
        return True
    return any(dst == f"raytrace.{q}" or dst.startswith(f"raytrace.{q}.") for q in ok if "." in q)


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for start in sorted(edges):
        if start in index:
            continue
        work = [(start, iter(sorted(edges.get(start, ()))))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            nxt = next(it, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on.add(nxt)
                    work.append((nxt, iter(sorted(edges.get(nxt, ())))))
                elif nxt in on:
                    low[v] = min(low[v], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def reachable(edges: dict[str, set[str]], a: str, b: str) -> bool:
    seen, todo = {a}, [a]
    while todo:
        v = todo.pop()
        if v == b:
            return True
        for w in edges.get(v, ()):
            if w not in seen:
                seen.add(w)
                todo.append(w)
    return False


def check(root: Path) -> list[str]:
    files = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            files[module_name(root, path)] = path
    known = set(files)
    problems: list[str] = []
    module_edges: dict[str, set[str]] = defaultdict(set)
    all_edges: dict[str, set[str]] = defaultdict(set)
    local_edges: list[tuple[str, str, int]] = []
    for mod, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        rel = path.relative_to(root)
        for dst, line, local in imports_of(tree, mod, path.name == "__init__.py", known):
            if dst == mod:
                continue
            if not allowed(mod, dst):
                problems.append(f"{rel}:{line}: {mod} imports {dst} (against the layers)")
            all_edges[mod].add(dst)
            if local:
                local_edges.append((mod, dst, line))
            else:
                module_edges[mod].add(dst)
    for comp in cycles(all_edges):
        problems.append(f"import cycle: {' -> '.join(comp)}")
    for src, dst, line in local_edges:
        if dst not in module_edges[src] and reachable(module_edges, dst, src):
            rel = files[src].relative_to(root)
            problems.append(
                f"{rel}:{line}: function-local import of {dst} dodges a cycle ({dst} imports "
                f"{src} at module level)"
            )
    return problems


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("root", nargs="?", type=Path, default=Path(__file__).resolve().parents[1],
                   help="the checkout to check (default: the one this file is in)")  # fmt: skip
    return p


def _main(args: argparse.Namespace) -> int:
    root = args.root
    missing = [pkg for pkg in PACKAGES if not (root / pkg).is_dir()]
    if missing:
        raise LayerCheckError(f"{root}: no {' or '.join(missing)} package in it (not a checkout)")
    problems = check(root)
    for p in problems:
        print(p)
    if problems:
        print(f"{len(problems)} layer violation(s)", file=sys.stderr)
        return 1
    print("layers ok")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(_main, parser(), argv, user_errors=(LayerCheckError,))


if __name__ == "__main__":
    raise SystemExit(main())
