"""``c20sim site build DIR``: the static site of the drive in a browser tab.

The site is files only, served by any static web server (GitHub Pages, ``python -m http.server``):

- ``index.html``, ``app.js``, ``serial.js``, ``style.css``: the page (``c20sim/browser/static``);
- ``c20sim.zip``: the modules the page imports, found by following the imports of
  :mod:`c20sim.browser.page` through the source (the pure core, the route table's operations, the line and
  its endpoint), with the shipped profiles, and the one-file modules they import from outside the standard
  library (``mypy_extensions``);
- ``pyodide/``: Python compiled to WebAssembly, copied from the ``pyodide`` npm package
  (``tools/site-deps`` installs the version ``tools/site/package-lock.json`` pins); the page loads it from
  the site itself, never from another host;
- ``build.json``: what went in, with the sizes.
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import json
import os
import shutil
import sys
import zipfile
from pathlib import Path

from ..wire.errors import C20SimError

__all__ = ["PYODIDE_FILES", "ROOT_MODULE", "add_site_command", "build", "find_pyodide", "modules"]

PACKAGE = Path(__file__).resolve().parents[1]
STATIC = Path(__file__).resolve().parent / "static"
#: The module the page imports; the zip holds it and everything it imports of c20sim.
ROOT_MODULE = "c20sim.browser.page"
#: The files of the pyodide npm package the page needs: the loader, the runtime, the standard library, and
#: the lock file the loader reads at start (no package of it is loaded).
PYODIDE_FILES = ("pyodide.mjs", "pyodide.asm.mjs", "pyodide.asm.wasm", "python_stdlib.zip", "pyodide-lock.json")
#: The pyodide npm package ``tools/site-deps`` installs, beside this package in a clone.
CLONE_PYODIDE = PACKAGE.parent / "tools" / "site" / "node_modules" / "pyodide"


def _module_file(name: str) -> Path | None:
    """The source of c20sim module ``name`` (a package's ``__init__.py``), or None if there is none."""
    path = PACKAGE.parent.joinpath(*name.split("."))
    if path.with_suffix(".py").is_file():
        return path.with_suffix(".py")
    if (path / "__init__.py").is_file():
        return path / "__init__.py"
    return None


def _optional(tree: ast.AST) -> set[int]:
    """Ids of the import nodes inside ``try: ... except ImportError``: a module used where installed (fastcrc)."""
    found: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try) and any(
            isinstance(h.type, ast.Name) and h.type.id in ("ImportError", "ModuleNotFoundError") for h in node.handlers
        ):
            found.update(id(inner) for stmt in node.body for inner in ast.walk(stmt))
    return found


def _imports(name: str, path: Path) -> set[str]:
    """Every module ``name`` (at ``path``) imports, but those it does without when they are not installed."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    optional = _optional(tree)
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in optional:
            continue
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


def modules(root: str = ROOT_MODULE) -> tuple[list[str], list[str]]:
    """(c20sim modules, outside modules): every module ``root`` imports, at the top or in a function, and
    theirs, with each package's ``__init__``; the outside ones are those not in the standard library."""
    inside: set[str] = set()
    outside: set[str] = set()
    todo = [root]
    while todo:
        name = todo.pop()
        parts = name.split(".")
        for i in range(1, len(parts) + 1):  # importing a.b.c runs a, a.b and a.b.c
            prefix = ".".join(parts[:i])
            path = _module_file(prefix)
            if path is None or prefix in inside:
                continue
            inside.add(prefix)
            for target in _imports(prefix, path):
                top = target.split(".")[0]
                if top == "c20sim":
                    if _module_file(target) is not None:
                        todo.append(target)
                elif top and top not in sys.stdlib_module_names and top != "__future__":
                    outside.add(top)
    return sorted(inside), sorted(outside)


def _outside_file(name: str) -> Path:
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None or spec.submodule_search_locations is not None:
        raise C20SimError(f"the page imports {name}, which is not a one-file module installed here")
    return Path(spec.origin)


def find_pyodide(given: str | None = None) -> Path:
    """The pyodide npm package's directory: ``given``, else $C20SIM_PYODIDE, else the clone's
    ``tools/site/node_modules/pyodide``, else ``./node_modules/pyodide``."""
    candidates = (
        [Path(given)]
        if given
        else [
            *([Path(os.environ["C20SIM_PYODIDE"])] if os.environ.get("C20SIM_PYODIDE") else []),
            CLONE_PYODIDE,
            Path("node_modules/pyodide"),
        ]
    )
    for candidate in candidates:
        missing = [f for f in PYODIDE_FILES if not (candidate / f).is_file()]
        if not missing:
            return candidate
        if given:
            raise C20SimError(
                f"--pyodide {given}: not the pyodide npm package (missing {', '.join(missing)}); "
                "run tools/site-deps, or npm install pyodide and give its node_modules/pyodide"
            )
    raise C20SimError(
        "no pyodide npm package found: run tools/site-deps (npm ci in tools/site), or give --pyodide DIR "
        "(the node_modules/pyodide of npm install pyodide)"
    )


def _zip(out: Path, inside: list[str], outside: list[str]) -> list[str]:
    written: list[str] = []
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in inside:
            path = _module_file(name)
            assert path is not None
            arcname = path.relative_to(PACKAGE.parent).as_posix()
            zf.write(path, arcname)
            written.append(arcname)
        profiles = PACKAGE / "profiles"
        if not profiles.is_dir():
            profiles = PACKAGE.parent / "profiles"  # a clone: the wheel puts them inside the package
        for profile in sorted(profiles.glob("*.toml")):
            zf.write(profile, f"c20sim/profiles/{profile.name}")
            written.append(f"c20sim/profiles/{profile.name}")
        for name in outside:
            path = _outside_file(name)
            zf.write(path, path.name)
            written.append(path.name)
    return written


def build(target: Path, pyodide: str | None = None) -> dict[str, object]:
    """Write the site into ``target`` (made if missing; the files it writes are replaced); returns build.json."""
    source = find_pyodide(pyodide)
    if target.exists() and not target.is_dir():
        raise C20SimError(f"{target}: not a directory")
    try:
        target.mkdir(parents=True, exist_ok=True)
        for page_file in sorted(STATIC.iterdir()):
            shutil.copyfile(page_file, target / page_file.name)
        (target / "pyodide").mkdir(exist_ok=True)
        for name in PYODIDE_FILES:
            shutil.copyfile(source / name, target / "pyodide" / name)
        version = json.loads((source / "package.json").read_text(encoding="utf-8")).get("version", "?")
        inside, outside = modules()
        zipped = _zip(target / "c20sim.zip", inside, outside)
        sizes = {
            p.relative_to(target).as_posix(): p.stat().st_size
            for p in sorted(target.rglob("*"))
            if p.is_file() and p.name != "build.json"
        }
        manifest: dict[str, object] = {
            "pyodide": version,
            "python_files": zipped,
            "bytes": sum(sizes.values()),
            "files": sizes,
        }
        (target / "build.json").write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    except OSError as exc:
        raise C20SimError(f"{target}: cannot write the site: {exc.strerror or exc}") from None
    return manifest


def cmd_site(args: argparse.Namespace) -> int:
    manifest = build(Path(args.dir), args.pyodide)
    total = manifest["bytes"]
    assert isinstance(total, int)
    print(
        f"c20sim site: {args.dir}: {total / 1e6:.1f} MB (pyodide {manifest['pyodide']}); "
        f"serve it as static files, such as: python3 -m http.server -d {args.dir} 8000"
    )
    return 0


def add_site_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    site = sub.add_parser("site", help="build the static site of the drive in a browser tab (docs/browser.md)")
    site.add_argument("action", choices=["build"], help="build: write the site into DIR")
    site.add_argument("dir", metavar="DIR", help="the directory to write (made if missing)")
    site.add_argument(
        "--pyodide",
        metavar="DIR",
        help="the pyodide npm package (node_modules/pyodide); default: tools/site's, from tools/site-deps",
    )
    site.set_defaults(func=cmd_site)
