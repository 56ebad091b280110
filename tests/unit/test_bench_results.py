"""bench/RESULTS.md holds one section for each bench script, with the command that produces its figure and the
commit and date that recorded it; a bench added, renamed or removed is said there too."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).parents[2]
BENCH = ROOT / "bench"
#: A section's command: one line, naming the script it runs as ``bench/NAME.py``.
COMMAND = re.compile(r"^Command: .*$", re.MULTILINE)
SCRIPT = re.compile(r"\bbench/(\w+\.py)\b")
#: The commit (an abbreviated hash) and the date a section's figure was recorded in.
FIGURE = re.compile(r"^Figure: recorded (\d{4}-\d{2}-\d{2}) in ([0-9a-f]{7,40})\b", re.MULTILINE)


def _has_main(path: Path) -> bool:
    """True if the script runs something when started: an ``if __name__ == "__main__":`` at its top level."""
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Compare):
            names = {n.id for n in ast.walk(node.test) if isinstance(n, ast.Name)}
            constants = {n.value for n in ast.walk(node.test) if isinstance(n, ast.Constant)}
            if "__name__" in names and "__main__" in constants:
                return True
    return False


def scripts() -> list[str]:
    """Every bench script with a main."""
    return sorted(path.name for path in BENCH.glob("*.py") if _has_main(path))


def sections() -> dict[str, str]:
    """RESULTS.md's sections (from one ``## `` heading to the next), by heading."""
    text = (BENCH / "RESULTS.md").read_text(encoding="utf-8")
    parts = re.split(r"^## ", text, flags=re.MULTILINE)[1:]
    return {part.splitlines()[0]: part for part in parts}


def section_scripts() -> dict[str, list[str]]:
    """The scripts each section's command lines name, by heading."""
    return {
        heading: sorted({name for line in COMMAND.findall(body) for name in SCRIPT.findall(line)})
        for heading, body in sections().items()
    }


def test_the_walk_finds_the_benches() -> None:
    found = scripts()
    assert len(found) > 20
    assert "bench_tcp.py" in found and "soak.py" in found
    assert "_common.py" not in found  # shared pieces, not a bench: no main
    assert _has_main(BENCH / "bench_mcp.py")  # an async main under the same guard


def test_every_bench_has_a_section_with_its_command() -> None:
    named = {name for names in section_scripts().values() for name in names}
    missing = [name for name in scripts() if name not in named]
    assert missing == [], "bench/RESULTS.md has no section whose Command: line names " + ", ".join(missing)


def test_every_section_runs_a_bench_that_is_there() -> None:
    benches = set(scripts())
    for heading, names in section_scripts().items():
        assert names, f"section {heading!r} has no Command: line naming a bench/NAME.py"
        gone = [name for name in names if name not in benches]
        assert gone == [], f"section {heading!r} runs scripts that are not benches in bench/: {gone}"


def test_one_section_a_bench_titled_by_its_script() -> None:
    """Each section's heading starts with the script it is about, once: today's figure has one place."""
    titles = [heading.split(":")[0] for heading in sections()]
    assert sorted(titles) == scripts()
    for heading, names in section_scripts().items():
        assert heading.split(":")[0] in names


def test_every_figure_says_when_and_where_it_was_recorded() -> None:
    for heading, body in sections().items():
        found = FIGURE.search(body)
        assert found is not None, f"section {heading!r} has no 'Figure: recorded YYYY-MM-DD in COMMIT' line"
