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
