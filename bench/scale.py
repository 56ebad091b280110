"""Scale: 247 drives on one bus, 8 buses in one process, all polled; and the CPU of an idle server.

1. One simulator with drives 1-247 (turnaround 0), in a child process; a
   client polls them round-robin (read 2100H, then write and read back 2001H),
   and the server's CPU time per request is recorded.
2. Eight simulators of 247 drives each (1976 drives) in one child process,
   each on its own TCP port; eight client connections poll every drive of
   every bus, round-robin over buses, from four client processes.
3. Idle: ``c20sim serve`` as a user starts it (realtime clock, pty, RTU over
   TCP and Modbus TCP, 247 drives) with no traffic; its CPU over ``--idle``
   seconds, from /proc/PID/stat. Target: under 1 % of a core.

    .venv/bin/python bench/scale.py --requests 20000 --idle 10
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from multiprocessing.connection import Connection
from pathlib import Path

from _common import CTX, ChildServer, RawRtuClient, ServerSpec, machine

from c20sim.wire.protocol import ReadRequest, WriteSingleRequest, encode
from c20sim.wire.registers import Reg

DRIVES = tuple(range(1, 248))


def poll(ports: list[int], count: int, conn: Connection | None = None) -> tuple[int, float]:
    """``count`` requests round-robin over every drive of every port; returns (requests, seconds)."""
    clients = [RawRtuClient("127.0.0.1", port, timeout=5.0) for port in ports]
    done = 0
    t0 = time.perf_counter()
    i = 0
    while done < count:
        client = clients[i % len(clients)]
        address = DRIVES[(i // len(clients)) % len(DRIVES)]
        value = i % 3001
        reply = client.transact(encode(ReadRequest(address, Reg.STATUS1, 1)))
        assert reply[0] == address and reply[1] == 0x03, reply.hex(" ")
        write = encode(WriteSingleRequest(address, Reg.SPEED_SETPOINT, value))
        assert client.transact(write) == write
        reply = client.transact(encode(ReadRequest(address, Reg.SPEED_SETPOINT, 1)))
        assert int.from_bytes(reply[3:5], "big") == value, reply.hex(" ")
        done += 3
        i += 1
    seconds = time.perf_counter() - t0
    for client in clients:
        client.close()
    if conn is not None:
        conn.send((done, seconds))
    return done, seconds


def _poll_child(ports: list[int], count: int, conn: Connection) -> None:
    poll(ports, count, conn)


def polled(spec: ServerSpec, requests: int, client_procs: int) -> dict[str, float]:
    server = ChildServer(spec)
    try:
        poll(server.ports, 300)  # warm up
        cpu0, rss0 = server.cpu_rss()
        t0 = time.perf_counter()
        if client_procs == 1:
            total, _ = poll(server.ports, requests)
        else:
            pipes, procs = [], []
            share = len(server.ports) // client_procs
            for k in range(client_procs):
                parent, child = CTX.Pipe()
                ports = server.ports[k * share : (k + 1) * share]
                proc = CTX.Process(target=_poll_child, args=(ports, requests // client_procs, child))
                proc.start()
                pipes.append(parent)
                procs.append(proc)
            total = sum(p.recv()[0] for p in pipes)
            for proc in procs:
                proc.join()
        wall = time.perf_counter() - t0
        cpu1, rss1 = server.cpu_rss()
        idle_cpu, idle_wall = server.measure_idle(5.0)
    finally:
        server.stop()
    return {
        "requests": total,
        "req_per_s": total / wall,
        "server_cpu_us_per_req": (cpu1 - cpu0) / total * 1e6,
        "rss_mib": rss1 / 1024,
        "rss_before_mib": rss0 / 1024,
        "idle_cpu_percent": idle_cpu / idle_wall * 100,
    }


def proc_cpu(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def idle_serve(seconds: float) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        ready = Path(tmp) / "ready.json"
        command = [sys.executable, "-m", "c20sim", "serve", "--pty", "--tcp", "127.0.0.1:0"]
        command.append("--no-bus-timing")  # the process's own cost, as recorded before bus timing (issue 27)
        command += ["--modbus-tcp", "127.0.0.1:0", "--drives", "1-247", "--clock", "realtime"]
        command += ["--ready-file", str(ready)]
        proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            deadline = time.monotonic() + 30
            while not ready.exists():
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"serve did not start: {proc.stderr.read() if proc.stderr else ''!r}")
                time.sleep(0.05)
            endpoints = json.loads(ready.read_text())
            # one request over RTU-over-TCP first, so that a served connection's idle cost counts too
            host, port = endpoints["tcp"].rsplit(":", 1)
            client = RawRtuClient(host, int(port))
            client.transact(encode(ReadRequest(1, Reg.STATUS1, 1)))
            time.sleep(1.0)  # let start-up work settle before measuring
            cpu0, t0 = proc_cpu(proc.pid), time.monotonic()
            time.sleep(seconds)
            cpu1, t1 = proc_cpu(proc.pid), time.monotonic()
            client.close()
        finally:
            proc.terminate()
            proc.wait(10)
    return {"idle_cpu_percent": (cpu1 - cpu0) / (t1 - t0) * 100, "seconds": t1 - t0}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--requests", type=int, default=20000, help="requests per scenario")
    parser.add_argument("--idle", type=float, default=10.0, help="seconds of idle serving to measure")
    args = parser.parse_args()
    print(f"scale, {time.strftime('%Y-%m-%d')}, {machine()}")
    one = polled(ServerSpec(addresses=DRIVES, turnaround_ms=0.0), args.requests, 1)
    eight = polled(ServerSpec(addresses=DRIVES, turnaround_ms=0.0, buses=8), args.requests, 4)
    rows = [("1 bus x 247 drives, 1 client", one), ("8 buses x 247 drives (1976), 4 clients", eight)]
    print()
    print("| scenario | requests | req/s | server CPU us/req | server RSS MiB | idle CPU % (5 s, after polling) |")
    print("|---|---|---|---|---|---|")
    for name, r in rows:
        print(
            f"| {name} | {r['requests']:.0f} | {r['req_per_s']:.0f} | {r['server_cpu_us_per_req']:.1f} "
            f"| {r['rss_mib']:.1f} | {r['idle_cpu_percent']:.2f} |"
        )
    idle = idle_serve(args.idle)
    print()
    print(
        f"c20sim serve --pty --tcp --modbus-tcp --drives 1-247 --clock realtime, no traffic: "
        f"{idle['idle_cpu_percent']:.2f} % of a core over {idle['seconds']:.1f} s (target < 1 %)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
