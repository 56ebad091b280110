"""Containers: image size, build time, start-to-ready of one container and of a 3-bus plant.

Builds the image with ``deploy/build-image`` (a fresh base from Debian's
packages, then the image on it), prints both sizes; then, ``--runs`` times
each, starts one container (``podman run -d -P``) and times it to the first
answer of drive 1 to a read of 2103H through the published RTU-over-TCP port,
and plays a plant of 3 buses x 4 drives (``podman kube play`` of ``c20sim
plant``) and times it to every drive answering through its bus's hostPort.
Everything is removed at the end. Needs root, podman, runc, catatonit and
mmdebstrap (deploy/ci-install); uses a containers.conf with ``default_ulimits
= []`` and ``runtime = "runc"`` as the test does.

    .venv/bin/python bench/bench_container.py [--runs 5]
"""

from __future__ import annotations

import argparse
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from c20sim.transport.probe import NoAnswer, Prober  # noqa: E402

BUSES, DRIVES = 3, (1, 2, 3, 4)


def podman(*args: str, env: dict[str, str], check: bool = True) -> str:
    result = subprocess.run(["podman", *args], env=env, capture_output=True, text=True, check=False, timeout=600)
    if check and result.returncode != 0:
        raise SystemExit(f"podman {' '.join(args)} exited {result.returncode}: {result.stderr.strip()}")
    return result.stdout


def answers(port: int, drive: int) -> bool:
    try:
        with Prober("127.0.0.1", port, timeout=0.5) as prober:
            return prober.read(drive, 0x2103) == 0x20
    except (NoAnswer, OSError):
        return False


def until(condition: Callable[[], bool], deadline: float = 120.0) -> None:
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > deadline:
            raise SystemExit(f"not ready within {deadline:g} s")
        time.sleep(0.02)


def free_base(count: int) -> int:
    for _ in range(100):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            base: int = s.getsockname()[1]
        if base + count > 65535:
            continue
        try:
            for port in range(base, base + count):
                with socket.socket() as s:
                    s.bind(("0.0.0.0", port))
        except OSError:
            continue
        return base
    raise SystemExit("no free run of ports")


def figures(name: str, values: list[float]) -> str:
    return (
        f"  {name:<26} median {statistics.median(values):6.2f} s  "
        f"min {min(values):6.2f}  max {max(values):6.2f}  ({len(values)} runs)"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="c20sim-bench-"))
    conf = work / "containers.conf"
    conf.write_text('[containers]\ndefault_ulimits = []\n\n[engine]\nruntime = "runc"\n')
    env = {**os.environ, "CONTAINERS_CONF": str(conf), "PYTHON": sys.executable}
    tag = f"localhost/c20sim-bench-{os.getpid()}:latest"
    base = f"localhost/c20sim-bench-base-{os.getpid()}:bookworm"
    one: list[float] = []
    plant: list[float] = []
    try:
        start = time.monotonic()
        build = subprocess.run(
            [str(ROOT / "deploy/build-image"), "--tag", tag, "--base", base],
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
        build_s = time.monotonic() - start
        if build.returncode != 0:
            raise SystemExit(f"deploy/build-image failed:\n{build.stderr}")
        size = int(podman("image", "inspect", "--format", "{{.Size}}", tag, env=env))
        base_size = int(podman("image", "inspect", "--format", "{{.Size}}", base, env=env))
        for run in range(args.runs):
            name = f"c20sim-bench-{os.getpid()}-{run}"
            start = time.monotonic()
            podman("run", "--detach", "--name", name, "--publish-all", tag, env=env)
            port = int(podman("port", name, "5020/tcp", env=env).strip().rsplit(":", 1)[1])
            until(lambda port=port: answers(port, 1))
            one.append(time.monotonic() - start)
            podman("rm", "--force", "--time", "5", name, env=env)
        for run in range(args.runs):
            rtu = modbus = free_base(BUSES)
            while abs(modbus - rtu) < BUSES:
                modbus = free_base(BUSES)
            manifest = work / f"plant-{run}.yaml"
            subprocess.run(
                [
                    *(sys.executable, "-m", "c20sim", "plant", "--buses", str(BUSES), "--drives", "1-4"),
                    *("--image", tag, "--name", f"c20sim-bench-{os.getpid()}-{run}"),
                    *("--rtu-port-base", str(rtu), "--modbus-port-base", str(modbus), "-o", str(manifest)),
                ],
                check=True,
            )
            start = time.monotonic()
            podman("kube", "play", str(manifest), env=env)
            until(lambda rtu=rtu: all(answers(rtu + bus, d) for bus in range(BUSES) for d in DRIVES))
            plant.append(time.monotonic() - start)
            podman("kube", "down", str(manifest), env=env)
    finally:
        podman("rmi", "--force", tag, base, env=env, check=False)
    print(
        f"containers: podman {podman('--version', env=env).split()[-1]}, {platform.machine()}, {os.cpu_count()} cores"
    )
    print(f"  image size                 {size / 1e6:.0f} MB (the Debian base {base_size / 1e6:.0f} MB of it)")
    print(f"  build (fresh base)         {build_s:.1f} s")
    for line in build.stderr.strip().splitlines():
        print(f"    {line}")
    print(figures("one container to ready", one))
    print(figures(f"{BUSES}-bus x {len(DRIVES)} plant to ready", plant))
    return 0


if __name__ == "__main__":
    sys.exit(main())
