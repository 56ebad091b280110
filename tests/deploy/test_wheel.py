"""c20sim in one's own project: the wheel the README's command builds carries the profiles, the scenarios and the
schemas, installs into a fresh venv, and its ``c20sim`` fixture runs the README's example there, away from this
clone.

The build is ``python -m build --wheel`` without isolation (its backend, hatchling, comes with the test extra, so
no download is needed for it); the fresh venv takes c20sim's dependencies and the example's (pytest,
pytest-asyncio, pymodbus) from the package index pip is set up for, through pip's cache.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "tests" / "examples" / "test_example_plugin.py"


def run(argv: list[str], cwd: Path, timeout: float) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env, check=False)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    built = run(
        [sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(out), str(ROOT)], ROOT, 300
    )
    assert built.returncode == 0, built.stdout + built.stderr
    [found] = out.glob("c20sim-*-py3-none-any.whl")
    return found


def test_the_wheel_carries_the_profiles_scenarios_and_schemas(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = {f"c20sim/profiles/{p.name}" for p in (ROOT / "profiles").glob("*.toml")}
    shipped |= {f"c20sim/scenarios/{p.name}" for p in (ROOT / "scenarios").glob("*.toml")}
    shipped |= {"c20sim/schemas/profile.schema.json", "c20sim/schemas/scenario.schema.json"}
    # the page c20sim site build writes from an installed c20sim (docs/browser.md)
    shipped |= {f"c20sim/browser/static/{p.name}" for p in (ROOT / "c20sim" / "browser" / "static").iterdir()}
    assert shipped <= names, sorted(shipped - names)
    assert not [n for n in names if n.startswith(("tests/", "bench/", ".venv/"))]


def test_the_wheel_in_a_fresh_venv_runs_the_fixture_example(wheel: Path, tmp_path: Path) -> None:
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    python = env_dir / "bin" / "python"
    installed = run(
        [str(python), "-m", "pip", "install", "-q", str(wheel), "pytest", "pytest-asyncio", "pymodbus>=3.16.1,<3.17"],
        tmp_path,
        600,
    )
    assert installed.returncode == 0, installed.stderr
    project = tmp_path / "project"  # a user's project: the example, and nothing of this clone
    project.mkdir()
    shutil.copy(EXAMPLE, project / "test_conveyor.py")
    where = run([str(python), "-c", "import c20sim; print(c20sim.__file__)"], project, 60)
    assert where.stdout.strip().startswith(str(env_dir)), where
    profiles = run([str(env_dir / "bin" / "c20sim"), "profiles"], project, 60)
    assert profiles.returncode == 0 and "c20-400hr" in profiles.stdout and "c20-2200hv" in profiles.stdout, profiles
    schema = run([str(env_dir / "bin" / "c20sim"), "schema", "scenario"], project, 60)
    assert schema.returncode == 0 and schema.stdout.startswith("{"), schema.stderr
    tested = run(
        [
            str(python),
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "-o",
            "asyncio_mode=auto",
            "-o",
            "asyncio_default_fixture_loop_scope=function",
            "test_conveyor.py",
        ],
        project,
        300,
    )
    assert tested.returncode == 0, tested.stdout + tested.stderr
    assert tested.stdout.splitlines()[-1].startswith("5 passed"), tested.stdout
