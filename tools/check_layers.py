#!/usr/bin/env python3
"""Check hallray's layers and house rules (docs/architecture.md, docs/tools.md); run by CI.

Rule groups (``--rules``, default all); each violation is one line ``path:line: what [rule]``:

``layers``
    an import that goes against the arrows between raytrace's subpackages (``LAYERS`` below) or
    between positioning's (``POSITIONING_LAYERS``); ``positioning`` importing ``raytrace``, or
    anything importing ``raytrace.cli``; ``hallray`` (the commands' shared infrastructure)
    importing ``raytrace`` or ``positioning`` (only its console command, ``hallray.main`` /
    ``hallray.cli``, may; nothing imports that); a raytrace layer below ``studies`` importing
    ``positioning`` (``emulation`` may import ``positioning.model``, the pure model floor), or any module importing an old (deprecated) path of positioning (a
    top-level module of it other than the package itself and ``positioning.errors``); a solver
    stage module imported by anything but the tracer; an import cycle between our modules
    (module-level and function-local imports together); a function-local import of our own
    module that would close a cycle if it were at module level (an import made only to dodge a
    cycle). Function-local imports that do not close a cycle are fine (lazy loading of heavy
    modules). Imports inside ``if TYPE_CHECKING:`` count like any other: a cycle of types is a
    cycle.
``size``
    a module over 800 lines, or a function over 100 lines (``def`` line to last line,
    decorators not counted), in the packages and tools/. A compiled numba kernel that would lose
    speed if split is exempt when its docstring contains the phrase ``long kernel:`` followed by
    the reason (:data:`LONG_KERNEL`).
``private``
    a private name (one leading underscore, not a dunder) of one of our modules used by another
    module: imported (``from .x import _y``) or read as an attribute of an imported module
    (``x._y``, ``raytrace.solver.x._y``). A private *module* (``raytrace._scenes``) is private
    to its package: importing it from inside that package is fine, from outside it is not.
    Checked in the packages and tools/; tests may reach into the private helpers they test.
``builtins``
    a public function's or method's parameter, or a public module-level name (function, class,
    variable), that shadows a Python builtin (``dir(builtins)`` minus
    :data:`BUILTINS_ALLOWED`), in the packages and tools/.
``syspath``
    ``sys.path`` changed in tools/ or tests/ (``sys.path.insert``, ``.append``, assignment, ...),
    or a module loaded by its file location (``importlib.util.spec_from_file_location``,
    ``runpy.run_path``, ``SourceFileLoader``): tools and tests import the installed package.

Exit status 1 if any rule is violated, 2 on bad input. Standard library only, apart from the
tools' harness.

Usage: ``python tools/check_layers.py [ROOT] [--rules layers,size,private,builtins,syspath]``
(ROOT default: the checkout this file is in).
"""

from __future__ import annotations

import argparse
import ast
import builtins
import sys
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path

try:  # the tools' harness (one-line errors, exit status 2 on bad input): standard library only
    from hallray.harness import OneLineParser, run_command
except ModuleNotFoundError:  # a checkout nothing is installed from: this checker reads sources
    # only, and CI-like hooks run it before any install; the same promises, in a few lines

    class OneLineParser(argparse.ArgumentParser):  # type: ignore[no-redef]
        def error(self, message: str) -> None:
            self.exit(2, f"error: {message}\n")

    def run_command(main, parser, argv=None, user_errors=()):  # type: ignore[no-redef]
        try:
            return main(parser.parse_args(argv))
        except user_errors as exc:
            print(f"error: {str(exc).splitlines()[0]}", file=sys.stderr)
            return 2


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
#: The raytrace layers below those that may import positioning's first floor, ``positioning.model``
#: (pure numpy: the pulse and peak fit that the tracer's receivers share with the twin's).
USES_POSITIONING_MODEL = {"emulation"}

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
        return layer_of(src) in USES_POSITIONING or (
            d == "model" and layer_of(src) in USES_POSITIONING_MODEL
        )
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


# =================================================================================================
# house rules (docs/tools.md): size, private names, builtins, sys.path
# =================================================================================================

#: The packages the size, private and builtins rules read (those present in the checkout).
PACKAGES = ("raytrace", "positioning", "hallray")
MAX_MODULE_LINES = 800
MAX_FUNCTION_LINES = 100
#: A function's docstring containing this phrase exempts it from MAX_FUNCTION_LINES: a compiled
#: numba kernel that would lose speed if split, the reason after the colon.
LONG_KERNEL = "long kernel:"
#: Builtins a public name may shadow: the site module's interactive banners, never called by code.
BUILTINS_ALLOWED = frozenset({"copyright", "credits", "license"})
#: Calls that load a module from a file location (a sys.path trick by other means).
LOAD_BY_PATH = frozenset({"spec_from_file_location", "SourceFileLoader", "addsitedir"})


def python_files(root: Path, folders: tuple[str, ...]) -> Iterator[tuple[Path, str]]:
    """``(path, module name)`` of every ``.py`` file under each of ``root/folders`` present."""
    for folder in folders:
        if (root / folder).is_dir():
            for path in sorted((root / folder).rglob("*.py")):
                yield path, module_name(root, path)


def parse(path: Path) -> ast.Module:
    """The syntax tree of a file (a file that is not Python is bad input: one line)."""
    try:
        return ast.parse(path.read_text(encoding="utf-8"), str(path))
    except (SyntaxError, UnicodeDecodeError) as exc:
        raise LayerCheckError(f"{path}: not valid Python ({exc})") from None


def is_private(name: str) -> bool:
    """One leading underscore and not a dunder (``_x``, ``__x``; not ``__x__``)."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def functions(
    tree: ast.Module,
) -> Iterator[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef, bool]]:
    """``(qualified name, node, public)`` of every function and method. Public: its name and
    every enclosing class's are not private, and it is not nested in a function."""

    def visit(node: ast.AST, prefix: str, public: bool, in_function: bool):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                pub = public and not in_function and not is_private(child.name)
                yield f"{prefix}{child.name}", child, pub
                yield from visit(child, f"{prefix}{child.name}.", False, True)
            elif isinstance(child, ast.ClassDef):
                pub = public and not in_function and not is_private(child.name)
                yield from visit(child, f"{prefix}{child.name}.", pub, in_function)
            else:
                yield from visit(child, prefix, public, in_function)

    yield from visit(tree, "", True, False)


def check_size(root: Path) -> list[str]:
    """Modules over MAX_MODULE_LINES lines, functions over MAX_FUNCTION_LINES (``def`` line to
    last line) unless their docstring has LONG_KERNEL, in the packages and tools/."""
    problems = []
    for path, _ in python_files(root, (*PACKAGES, "tools")):
        rel = path.relative_to(root)
        text = path.read_text(encoding="utf-8")
        n = len(text.splitlines())
        if n > MAX_MODULE_LINES:
            problems.append(f"{rel}:1: module has {n} lines (over {MAX_MODULE_LINES})")
        for name, node, _ in functions(parse(path)):
            length = node.end_lineno - node.lineno + 1
            if length > MAX_FUNCTION_LINES and LONG_KERNEL not in (ast.get_docstring(node) or ""):
                problems.append(
                    f"{rel}:{node.lineno}: function {name} has {length} lines "
                    f"(over {MAX_FUNCTION_LINES}; a numba kernel may say '{LONG_KERNEL}' why)"
                )
    return problems


def import_base(node: ast.ImportFrom, mod: str, is_pkg: bool) -> str:
    """The absolute module a ``from ... import`` reads from."""
    if not node.level:
        return node.module or ""
    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def outside_private_module(target: str, importer: str) -> str | None:
    """The package whose private module ``target`` is (or is in), if ``importer`` is outside
    that package; else None."""
    parts = target.split(".")
    for k, part in enumerate(parts):
        if is_private(part):
            package = ".".join(parts[:k])
            if not (importer == package or importer.startswith(package + ".")):
                return package
    return None


def check_private(root: Path) -> list[str]:
    """Private names of our modules used by another module: imported, or read as an attribute
    of an imported module; private modules imported from outside their package. In the packages
    and tools/ (not tests/: a test may check a module's private helpers)."""
    known = {name for _, name in python_files(root, PACKAGES)}
    problems = []
    for path, mod in python_files(root, (*PACKAGES, "tools")):
        rel = path.relative_to(root)
        tree = parse(path)
        is_pkg = path.name == "__init__.py"
        bound: dict[str, str] = {}  # local name -> our module it refers to
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    pkg = outside_private_module(a.name, mod)
                    if pkg is not None and a.name.split(".")[0] in PACKAGES:
                        problems.append(f"{rel}:{node.lineno}: imports {a.name}, private to {pkg}")
                    if a.asname:
                        bound[a.asname] = a.name
                    else:
                        bound[a.name.split(".")[0]] = a.name.split(".")[0]
            elif isinstance(node, ast.ImportFrom):
                base = import_base(node, mod, is_pkg)
                if base.split(".")[0] not in PACKAGES:
                    continue
                for a in node.names:
                    sub = f"{base}.{a.name}"
                    target = sub if sub in known else base
                    pkg = outside_private_module(target, mod)
                    if pkg is not None:
                        problems.append(f"{rel}:{node.lineno}: imports {target}, private to {pkg}")
                    elif target == base and base != mod and is_private(a.name):
                        problems.append(
                            f"{rel}:{node.lineno}: imports private name {a.name} from {base}"
                        )
                    if sub in known:
                        bound[a.asname or a.name] = sub
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and is_private(node.attr)):
                continue
            chain, value = [], node.value
            while isinstance(value, ast.Attribute):
                chain.append(value.attr)
                value = value.value
            if not (isinstance(value, ast.Name) and value.id in bound):
                continue
            owner = ".".join([bound[value.id], *reversed(chain)])
            if owner in known and owner != mod:
                problems.append(f"{rel}:{node.lineno}: uses private name {node.attr} of {owner}")
    return problems


def shadowing_builtins() -> frozenset[str]:
    """The builtins a public name must not shadow."""
    return frozenset(n for n in dir(builtins) if not n.startswith("_")) - BUILTINS_ALLOWED


def module_level_names(tree: ast.Module) -> Iterator[tuple[str, int]]:
    """``(name, line)`` of every name bound at module level: functions, classes, imports,
    assignment and loop targets (also inside top-level ``if``, ``try``, ``with``, ``for``)."""

    def visit(node: ast.AST):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                yield child.name, child.lineno
            elif isinstance(child, (ast.Import, ast.ImportFrom)):
                if isinstance(child, ast.ImportFrom) and child.module == "__future__":
                    continue
                for a in child.names:
                    if a.name != "*":
                        yield a.asname or a.name.split(".")[0], child.lineno
            elif isinstance(child, ast.Name) and isinstance(child.ctx, ast.Store):
                yield child.id, child.lineno
            elif not isinstance(child, (ast.Lambda, ast.comprehension, ast.expr)) or isinstance(
                child, (ast.Tuple, ast.List, ast.Starred, ast.NamedExpr)
            ):
                yield from visit(child)

    yield from visit(tree)


def check_builtins(root: Path) -> list[str]:
    """Public functions' and methods' parameters and public module-level names that shadow a
    builtin, in the packages and tools/."""
    names = shadowing_builtins()
    problems = []
    for path, _ in python_files(root, (*PACKAGES, "tools")):
        rel = path.relative_to(root)
        tree = parse(path)
        for name, line in module_level_names(tree):
            if name in names:
                problems.append(f"{rel}:{line}: module-level name {name} shadows the builtin")
        for qual, node, public in functions(tree):
            if not public:
                continue
            a = node.args
            params = [*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg]
            for p in params:
                if p is not None and p.arg in names:
                    problems.append(
                        f"{rel}:{p.lineno}: parameter {p.arg} of {qual} shadows the builtin"
                    )
    return problems


def _dotted(node: ast.AST) -> str:
    """``a.b.c`` of a Name/Attribute chain, else ''."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
        return ".".join(reversed(parts))
    return ""


def check_syspath(root: Path) -> list[str]:
    """``sys.path`` changed, or a module loaded by its file location, in tools/ or tests/."""
    problems = []
    for path, _ in python_files(root, ("tools", "tests")):
        rel = path.relative_to(root)
        for node in ast.walk(parse(path)):
            what = None
            if isinstance(node, ast.ImportFrom) and node.module == "sys":
                if any(a.name == "path" for a in node.names):
                    what = "imports sys.path by name"
            elif isinstance(node, ast.Call):
                func = _dotted(node.func)
                if func.startswith("sys.path."):
                    what = f"calls {func}"
                elif func.rpartition(".")[2] in LOAD_BY_PATH or func == "runpy.run_path":
                    what = f"loads a module by its file location ({func})"
            elif isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign, ast.Delete)):
                targets = (
                    node.targets if isinstance(node, (ast.Assign, ast.Delete)) else [node.target]
                )
                for t in targets:
                    if _dotted(t.value if isinstance(t, ast.Subscript) else t) == "sys.path":
                        what = "assigns to sys.path"
            if what:
                problems.append(f"{rel}:{node.lineno}: {what}")
    return problems


#: Rule group -> its check (each returns lines ``path:line: what``).
RULES: dict[str, Callable[[Path], list[str]]] = {
    "layers": check,
    "size": check_size,
    "private": check_private,
    "builtins": check_builtins,
    "syspath": check_syspath,
}


def rule_list(text: str) -> list[str]:
    """``--rules``: comma-separated rule groups (argparse type)."""
    rules = [r.strip() for r in text.split(",") if r.strip()]
    unknown = [r for r in rules if r not in RULES]
    if unknown or not rules:
        raise argparse.ArgumentTypeError(
            f"unknown rule group {unknown[0] if unknown else text!r} (known: {', '.join(RULES)})"
        )
    return list(dict.fromkeys(rules))


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("root", nargs="?", type=Path, default=Path(__file__).resolve().parents[1],
                   help="the checkout to check (default: the one this file is in)")  # fmt: skip
    p.add_argument("--rules", type=rule_list, default=list(RULES), metavar="R1,R2",
                   help=f"rule groups to check (default all: {','.join(RULES)})")  # fmt: skip
    return p


def _main(args: argparse.Namespace) -> int:
    root = args.root
    missing = [pkg for pkg in PACKAGES if not (root / pkg).is_dir()]
    if missing:
        raise LayerCheckError(f"{root}: no {' or '.join(missing)} package in it (not a checkout)")
    broken = set()
    for rule in args.rules:
        for problem in RULES[rule](root):
            print(f"{problem} [{rule}]")
            broken.add(rule)
    if broken:
        failed = [r for r in args.rules if r in broken]
        print(f"house rules violated: {', '.join(failed)}", file=sys.stderr)
        return 1
    print(f"ok: {', '.join(args.rules)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(_main, parser(), argv, user_errors=(LayerCheckError,))


if __name__ == "__main__":
    raise SystemExit(main())
