"""Soak: a million requests over RTU-over-TCP from 4 concurrent clients, with random link faults.

The server (drives 1-4, realtime clock, the profile's turnaround set to 0)
runs in a child process; a timer on its loop switches the bus's link faults
at random every ``--fault-period`` seconds (drop a share of replies, drop the
next few, corrupt the CRC, delay with jitter, cut short, garbage before; half
the time none). Four client processes each own a drive: they write 2001H with
their own sequence of values and read it back, over and over.

Checked for every reply: the address is the client's drive, a write reply
echoes the write, and a read returns the last acknowledged value (or a write
whose reply was lost: it may have landed). A faulted reply is a timeout or a
bad frame at the client, never a wrong answer; the client then reconnects.
The server must not log an error or die. RSS of the server is sampled.

    .venv/bin/python bench/soak.py --requests 1000000 --seconds 1800
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import time
from dataclasses import asdict, dataclass, field
from multiprocessing.connection import Connection

from _common import CTX, ChildServer, RawRtuClient, ReplyError, ServerSpec, machine

from c20sim.wire.protocol import ReadRequest, WriteSingleRequest, decode_response, encode
from c20sim.wire.registers import Reg

CLIENTS = 4


@dataclass
class ClientStats:
    address: int
    requests: int = 0
    ok: int = 0
    timeouts: int = 0
    bad_frames: int = 0
    exceptions: int = 0
    wrong: int = 0
    stale_landed: int = 0  #: a read returned a write whose reply was lost: allowed
    reconnects: int = 0
    wrong_examples: list[str] = field(default_factory=list)


def client_main(port: int, address: int, quota: int, deadline: float, timeout: float, conn: Connection) -> None:
    stats = ClientStats(address)
    client = RawRtuClient("127.0.0.1", port, timeout)
    acked = -1  # unknown until the first acknowledged write
    unacked: collections.deque[int] = collections.deque(maxlen=64)
    seq = 0
    while stats.requests < quota and time.monotonic() < deadline:
        seq += 1
        value = (seq * 7 + address) % 3001
        for request in (
            WriteSingleRequest(address, Reg.SPEED_SETPOINT, value),
            ReadRequest(address, Reg.SPEED_SETPOINT, 1),
        ):
            stats.requests += 1
            try:
                reply = client.transact(encode(request))
            except (TimeoutError, ReplyError, ConnectionError) as exc:
                if isinstance(exc, TimeoutError):
                    stats.timeouts += 1
                else:
                    stats.bad_frames += 1
                if isinstance(request, WriteSingleRequest):
                    unacked.append(value)
                client.reconnect()
                stats.reconnects += 1
                break  # start the next pair on the fresh connection
            response = decode_response(reply)
            problem = ""
            if response.slave != address:
                problem = f"reply from {response.slave}"
            elif response.function & 0x80:
                stats.exceptions += 1
                problem = f"exception {reply.hex(' ')}"
            elif isinstance(request, WriteSingleRequest):
                if reply != encode(request):  # a write reply echoes the request
                    problem = "write reply is not the echo"
                else:
                    acked = value
            else:
                got = decode_response(reply)
                read = getattr(got, "values", (None,))[0]
                if read == acked or acked == -1:
                    pass
                elif read in unacked:
                    stats.stale_landed += 1
                else:
                    problem = f"read {read}, acknowledged {acked}, unacknowledged {list(unacked)[-4:]}"
            if problem:
                stats.wrong += 1
                if len(stats.wrong_examples) < 10:
                    stats.wrong_examples.append(f"{request}: {problem}")
            else:
                stats.ok += 1
    client.close()
    conn.send(stats)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--requests", type=int, default=1_000_000, help="total requests over all clients")
    parser.add_argument("--seconds", type=float, default=1800, help="stop after this long, whatever the count")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--fault-period", type=float, default=1.0, help="seconds between link-fault switches")
    parser.add_argument("--no-faults", action="store_true")
    parser.add_argument(
        "--self-check",
        action="store_true",
        help="also inject replies from a wrong address: the run must then FAIL with wrong answers",
    )
    parser.add_argument("--timeout", type=float, default=0.25, help="client reply timeout (s)")
    parser.add_argument("--sample", type=float, default=30.0, help="seconds between RSS samples")
    parser.add_argument("--json", help="also write the results to this file")
    args = parser.parse_args()

    server = ChildServer(
        ServerSpec(
            addresses=tuple(range(1, CLIENTS + 1)),
            turnaround_ms=0.0,
            seed=args.seed,
            faults=None if args.no_faults else ("random+wrong" if args.self_check else "random"),
            fault_period=args.fault_period,
        )
    )
    _, rss0 = server.cpu_rss()
    t0 = time.monotonic()
    deadline = t0 + args.seconds
    quota = -(-args.requests // CLIENTS)
    pipes, procs = [], []
    for i in range(CLIENTS):
        parent, child = CTX.Pipe()
        proc = CTX.Process(target=client_main, args=(server.port, i + 1, quota, deadline, args.timeout, child))
        proc.start()
        pipes.append(parent)
        procs.append(proc)
    samples = [(0.0, rss0)]
    while any(p.is_alive() for p in procs) and not all(p.poll() for p in pipes):
        for p in pipes:
            p.poll(min(args.sample, 5.0) / CLIENTS)
        elapsed = time.monotonic() - t0
        if elapsed - samples[-1][0] >= args.sample:
            if not server.process.is_alive():
                break
            samples.append((round(elapsed, 1), server.cpu_rss()[1]))
            print(f"  {elapsed:7.0f} s  server RSS {samples[-1][1]} KiB", flush=True)
    stats: list[ClientStats] = [p.recv() for p in pipes]
    wall = time.monotonic() - t0
    for proc in procs:
        proc.join()
    alive = server.process.is_alive()
    server_cpu, rss_end = server.cpu_rss() if alive else (float("nan"), 0)
    report = server.stop() if alive else None
    total = sum(s.requests for s in stats)
    summary = {
        "date": time.strftime("%Y-%m-%d"),
        "machine": machine(),
        "command": "bench/soak.py " + " ".join(sys.argv[1:]),
        "requests": total,
        "wall_s": round(wall, 1),
        "requests_per_s": round(total / wall),
        "ok": sum(s.ok for s in stats),
        "timeouts": sum(s.timeouts for s in stats),
        "bad_frames": sum(s.bad_frames for s in stats),
        "exceptions": sum(s.exceptions for s in stats),
        "wrong_answers": sum(s.wrong for s in stats),
        "stale_writes_landed": sum(s.stale_landed for s in stats),
        "reconnects": sum(s.reconnects for s in stats),
        "server_alive": alive,
        "server_errors_logged": report.errors_logged if report else None,
        "fault_switches": report.faults_switched if report else None,
        "server_cpu_s": round(server_cpu, 1),
        "rss_start_kib": rss0,
        "rss_end_kib": rss_end,
        "rss_samples": samples,
        "clients": [asdict(s) for s in stats],
    }
    print(json.dumps({k: v for k, v in summary.items() if k not in ("clients", "rss_samples")}, indent=1))
    for s in stats:
        for example in s.wrong_examples:
            print("WRONG:", example)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(summary, f, indent=1)
    ok = alive and summary["wrong_answers"] == 0 and summary["exceptions"] == 0 and summary["server_errors_logged"] == 0
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
