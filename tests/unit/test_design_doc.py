"""docs/design.md says only what the code has: every module, class, function, option, route and command it names
in backticks exists, and every file it or the README names is in the repository.

A name that comes from another project (h11's ``_state.py``, SimPy's ``Environment``, Textual's ``reactive``) is
in :data:`ELSEWHERE`, which must itself stay true to the page: each of its names is still on it.
"""

from __future__ import annotations

import ast
import importlib
import os
import re
import sys
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest

from c20sim.cli import build_parser
from c20sim.control import routes

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "c20sim"
DESIGN = ROOT / "docs" / "design.md"
README = ROOT / "README.md"

#: Names design.md cites from other projects, or words in backticks that are not code of ours.
ELSEWHERE = {
    "_state.py": "h11's state machine module",
    "Opcode": "wsproto's frame opcodes",
    "error_code": "uModbus's exception attribute",
    "conf": "uModbus's global settings",
    "Environment": "SimPy",
    "RealtimeEnvironment": "SimPy",
    "reactive": "Textual",
    "DEFAULT_CSS": "Textual",
    "App.run_test()": "Textual",
    "pytest11": "pytest's entry-point group (pyproject.toml)",
    "filterwarnings": "pytest's setting (pyproject.toml)",
    "getpid()": "the system call",
    "mbpoll": "Debian's Modbus master",
    "#:": "Sphinx's attribute-comment marker",
    ".tcss": "Textual's CSS files' extension",
    "if": "the keyword",
    "t": "a time, as in drive.advance_to(t)",
}
#: Files the README's examples have a user make (a ready file, a profile of their own, a report): not ours.
USER_FILES = {"ready.json", "mydrive.toml", "FILE.md"}
#: How a file's name ends when the docs name a file.
EXTENSIONS = ("py", "md", "c", "toml", "json", "yaml", "tcss", "js", "html", "css", "tmpl")


def _spans() -> list[str]:
    return sorted(set(re.findall(r"`([^`\n]+)`", DESIGN.read_text(encoding="utf-8"))))


def _repo_files() -> list[str]:
    skip = {".git", ".venv", "node_modules", "__pycache__", ".ruff_cache", ".mypy_cache", ".pytest_cache"}
    found = []
    for folder, dirs, files in os.walk(ROOT):
        dirs[:] = [d for d in dirs if d not in skip and not d.endswith(".egg-info")]
        here = Path(folder).relative_to(ROOT).as_posix()
        prefix = "" if here == "." else here + "/"
        found += [f"{prefix}{d}/" for d in dirs] + [prefix + f for f in files]
    return found


FILES = _repo_files()


class Index:
    """What the package defines, read from its source: modules, classes and their members, module members."""

    def __init__(self) -> None:
        self.modules: dict[str, set[str]] = {}  #: dotted module name (no "c20sim.") -> its top-level names
        self.classes: dict[str, set[str]] = defaultdict(set)  #: class name -> its members (any module)
        self.bases: dict[str, set[str]] = defaultdict(set)
        self.names: set[str] = set()  #: every name defined anywhere, attributes included
        for path in PACKAGE.rglob("*.py"):
            parts = path.relative_to(PACKAGE).with_suffix("").parts
            module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            self.names.update(parts)
            self.modules[module] = self._read(ast.parse(path.read_text(encoding="utf-8")))

    def _read(self, tree: ast.Module) -> set[str]:
        top: set[str] = set()
        for node in tree.body:
            top.update(_defined(node))
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                members = self.classes[node.name]
                for item in node.body:
                    members.update(_defined(item))
                for sub in ast.walk(node):  # self.x = ... in its methods
                    if isinstance(sub, ast.Attribute) and isinstance(sub.ctx, ast.Store):
                        members.add(sub.attr)
                self.bases[node.name].update(b.id for b in node.bases if isinstance(b, ast.Name))
                self.names.update(members)
            self.names.update(_defined(node))
            if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                self.names.add(node.attr)
        return top

    def members(self, cls: str, seen: frozenset[str] = frozenset()) -> set[str]:
        found = set(self.classes.get(cls, ()))
        for base in self.bases.get(cls, ()):
            if base not in seen:
                found |= self.members(base, seen | {cls})
        return found

    def modules_named(self, dotted: str) -> list[str]:
        """The package's modules whose dotted name is ``dotted`` or ends with ``.dotted``."""
        return [m for m in self.modules if m == dotted or m.endswith("." + dotted)]

    def resolves(self, parts: list[str]) -> bool:
        """True if ``a.b.c`` names something the package (or the standard library) has."""
        if parts[0] in sys.stdlib_module_names:
            return _has_attributes(importlib.import_module(parts[0]), parts[1:])
        for cut in range(len(parts) - 1, 0, -1):
            for module in self.modules_named(".".join(parts[:cut])):
                rest = parts[cut:]
                if rest[0] in self.modules[module] or ".".join([module, rest[0]]) in self.modules:
                    return len(rest) == 1 or rest[1] in self.members(rest[0]) or rest[1] in self.names
        if parts[0] in self.classes:
            return all(part in self.members(parts[0]) for part in parts[1:2])
        if len(parts) == 1:
            return parts[0] in self.names or _importable(parts[0])
        # a variable's attributes (framer.next_event, sim.bus.records.clear): each defined somewhere
        return all(part in self.names or any(hasattr(t, part) for t in (list, dict, set)) for part in parts[1:])


def _defined(node: ast.AST) -> Iterator[str]:
    if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
        yield node.name
    elif isinstance(node, ast.Assign):
        for target in node.targets:
            yield from (n.id for n in ast.walk(target) if isinstance(n, ast.Name))
    elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
        yield node.target.id


def _has_attributes(value: object, names: list[str]) -> bool:
    for name in names:
        if not hasattr(value, name):
            return False
        value = getattr(value, name)
    return True


def _importable(name: str) -> bool:
    try:
        importlib.import_module(name)
    except ImportError:
        return False
    return True


INDEX = Index()


def _file_exists(name: str, here: Path = ROOT) -> bool:
    """``name`` is a file or folder of the repository: from the root, from ``c20sim/``, from the naming page's
    folder, or the tail of a path in the repository (``drive/files.py``, ``test_counters.py``)."""
    name = name.rstrip("/")
    for base in (ROOT, PACKAGE, here):
        if (base / name).exists() or (base / f"{name}.py").exists():
            return True
    return any(f.rstrip("/") == name or f.rstrip("/").endswith("/" + name) for f in FILES)


def _commands() -> set[str]:
    parser = build_parser()
    for action in parser._actions:  # argparse keeps its subcommands here
        if action.dest == "command":
            return set(action.choices or ())
    raise AssertionError("c20sim's parser has no subcommands")


def _routes() -> set[tuple[str, str]]:
    return {(row.method, row.path) for row in routes.table().values()}


def _option_known(option: str) -> bool:
    quoted = f'"{option}"'
    return any(quoted in p.read_text(encoding="utf-8") for d in ("c20sim", "bench") for p in (ROOT / d).rglob("*.py"))


def check(span: str) -> str | None:
    """None if the backticked ``span`` names something that exists, else why not."""
    if span in ELSEWHERE:
        return None
    words = span.split()
    if len(words) > 1:
        if words[0] == "c20sim":
            return None if words[1] in _commands() else f"c20sim has no command {words[1]!r}"
        if words[0] in ("GET", "POST", "PUT", "DELETE", "PATCH"):
            return None if (words[0], words[1]) in _routes() else f"no route {words[0]} {words[1]} in the table"
        if words[0].endswith(".py"):
            missing = [w for w in words[1:] if w.startswith("--") and not _option_known(w)]
            return check(words[0]) or (f"no option {missing}" if missing else None)
        return None  # a phrase (mypy --strict, git show ...): not a name
    if span.startswith("{"):
        return None  # a JSON shape ({cause}), not a name
    if span.startswith("--"):
        return None if _option_known(span) else f"no source file defines the option {span}"
    if span.startswith("/"):
        return None if any(path == span for _, path in _routes()) else f"no route path {span}"
    name = re.sub(r"\(.*\)$", "", span)
    if "/" in name:
        if _file_exists(name):
            return None
        path, _, attribute = name.rpartition(".")
        module = path.replace("/", ".")
        if path and _file_exists(path) and INDEX.resolves([*module.split("."), attribute]):
            return None
        return f"no file or module {name}"
    if name.rsplit(".", 1)[-1] in EXTENSIONS:
        return None if _file_exists(name) else f"no file {name} in the repository"
    return None if INDEX.resolves(name.split(".")) else f"the package defines no {name}"


def test_the_index_is_read() -> None:
    assert "present" in INDEX.members("Machine")
    assert "transaction_time" in INDEX.modules["wire.protocol"]
    assert "serve" in _commands()
    assert ("DELETE", "/frames") in _routes()


@pytest.mark.parametrize(
    "span",
    [
        "Machine.nowhere",
        "framer.next_frame()",
        "Nowhere",
        "drive/nowhere.py",
        "c20sim nowhere",
        "GET /nowhere",
        "--no-such-option",
        "wire/values.nowhere",
        "causes.NOWHERE",
        "nowhere.py",
    ],
)
def test_a_name_that_is_not_there_is_found_out(span: str) -> None:
    assert check(span) is not None


def test_every_name_design_md_gives_in_backticks_exists() -> None:
    wrong = {span: why for span in _spans() if (why := check(span)) is not None}
    assert wrong == {}


def test_every_name_kept_as_from_elsewhere_is_still_on_the_page() -> None:
    assert sorted(set(ELSEWHERE) - set(_spans())) == []


def _file_names(text: str) -> set[str]:
    """Words of ``text`` that name a file or folder of ours: ``dir/...`` under a top folder or a package folder,
    or ``name.ext`` with a file's extension; URLs, globs and absolute paths are not names of ours."""
    tops = {f.split("/")[0] for f in FILES if f.endswith("/") and f.count("/") == 1}
    tops |= {p.name for p in PACKAGE.iterdir() if p.is_dir()}
    found = set()
    for word in re.findall(r"[\w./*{}~:-]+", text):
        word = word.strip(".:,")
        if not word or any(c in word for c in "*{}~") or "://" in word or word.startswith(("/", ".")):
            continue
        first, ext = word.split("/")[0], word.rsplit(".", 1)[-1] if "." in word else ""
        if "/" in word and "." in word.rsplit("/", 1)[-1] and ext not in EXTENSIONS:
            word, ext = word.rsplit(".", 1)[0], ""  # wire/values.quick_init: the module's file
        if ("/" in word and first in tops) or (ext in EXTENSIONS and re.fullmatch(r"[\w./-]+", word)):
            found.add(word)
    return found


@pytest.mark.parametrize("page", [DESIGN, README], ids=lambda p: p.name)
def test_every_file_the_page_names_exists(page: Path) -> None:
    names = _file_names(page.read_text(encoding="utf-8"))
    assert len(names) > 20  # the page was read
    ours = names - USER_FILES - set(ELSEWHERE)
    missing = sorted(name for name in ours if not _file_exists(name, page.parent))
    assert missing == []


def test_the_users_own_files_are_still_in_the_readme() -> None:
    assert _file_names(README.read_text(encoding="utf-8")) >= USER_FILES


def test_a_file_that_is_not_there_is_found_out() -> None:
    names = _file_names("see docs/nowhere.md and drive/gone.py, https://example.org/x.py, DIR/*.toml")
    assert names == {"docs/nowhere.md", "drive/gone.py"}
    assert not any(_file_exists(name) for name in names)
