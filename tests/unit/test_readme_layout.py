"""README's Layout names every module of the package: a module added, moved or renamed is said there too."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).parents[2]


def layout() -> str:
    """The README's Layout block (the code fence after ``## Layout``)."""
    text = (ROOT / "README.md").read_text()
    section = text[text.index("\n## Layout\n") :]
    start = section.index("```\n") + 4
    return section[start : section.index("```", start)]


def test_the_layout_names_every_module() -> None:
    block = layout()
    modules = sorted(
        path.relative_to(ROOT).as_posix()
        for path in (ROOT / "c20sim").rglob("*.py")
        if path.name not in ("__init__.py", "__main__.py")
    )
    assert len(modules) > 80  # the walk found the package
    unnamed = [module for module in modules if Path(module).name not in block]
    assert unnamed == [], "README's Layout does not name these modules: " + ", ".join(unnamed)


def test_the_layout_names_no_module_that_is_gone() -> None:
    """Every ``NAME.py`` the Layout mentions exists in the package, or the path it gives exists."""
    block = layout()
    names = {word.strip("(),;:") for word in block.split() if word.strip("(),;:").endswith(".py")}
    present = {path.name for path in (ROOT / "c20sim").rglob("*.py")}
    present |= {name for name in names if "/" in name and (ROOT / name).exists()}
    assert sorted(names - present) == []


def test_the_layout_names_every_doc_and_test_folder() -> None:
    """Each page of docs/, each folder of tests/ and each script of tools/ is named in the Layout."""
    block = layout()
    words = {word.strip("(),;:") for word in block.split()}
    docs = sorted(path.name for path in (ROOT / "docs").glob("*.md"))
    folders = sorted(f"{path.name}/" for path in (ROOT / "tests").iterdir() if (path / "__init__.py").is_file())
    tools = sorted(f"tools/{path.name}" for path in (ROOT / "tools").iterdir() if path.is_file())
    assert len(docs) > 10 and "unit/" in folders and "tools/compile-core" in tools  # the walks found them
    unnamed = [name for name in docs if name not in words]
    in_tests = {word.strip("(),;:") for word in _entry(block, "tests/").split()}
    unnamed += [f"tests/{name}" for name in folders if name not in in_tests]
    unnamed += [name for name in tools if name not in block and name.removeprefix("tools/") not in words]
    assert unnamed == [], "README's Layout does not name these: " + ", ".join(unnamed)


def _entry(block: str, top: str) -> str:
    """The Layout's entry for the top-level folder ``top``: its line and the indented lines under it."""
    lines = block.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(top + " "))
    end = next((i for i in range(start + 1, len(lines)) if lines[i][:1] not in (" ", "")), len(lines))
    return "\n".join(lines[start:end]).removeprefix(top)
