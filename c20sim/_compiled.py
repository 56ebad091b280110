"""Says, on stderr, when a module tools/compile-core compiled is older than its source: Python would run the
old code. Imported first by the package, before any module that may be compiled."""

import sys
from pathlib import Path

__all__ = ["compiled_before_their_source"]


def compiled_before_their_source() -> list[str]:
    """Modules tools/compile-core compiled whose source changed since (paths from the checkout's root)."""
    here = Path(__file__).parent
    return sorted(
        str(source.relative_to(here.parent))
        for compiled in here.rglob("*.cpython-*.so")
        if (source := compiled.with_name(compiled.name.split(".", 1)[0] + ".py")).exists()
        and source.stat().st_mtime > compiled.stat().st_mtime
    )


if stale := compiled_before_their_source():
    print(
        f"c20sim: warning: {', '.join(stale)} changed after tools/compile-core compiled them, and the compiled"
        " code runs: run tools/compile-core again, or tools/compile-core --remove",
        file=sys.stderr,
    )
