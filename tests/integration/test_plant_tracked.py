"""A serving process keeps nothing a frame that the garbage collector walks: buses served over real TCP ports,
the live audit and bus timing on, then every object a frame makes is gone or untracked once collected."""

from __future__ import annotations

import asyncio
import collections
import dataclasses
import gc

from c20sim.core.bus import FrameRecord
from c20sim.core.clock import RealtimeClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.serve import ServeOptions, Server
from c20sim.transport.line import _Waiting
from c20sim.wire.protocol import FrameEvent, ReadRequest, ReadResponse, encode
from c20sim.wire.registers import Reg

BUSES = 6
READS = 150  #: a bus, one after the other: 2 frame records each, past the live audit's batch of 32


async def _poll(port: int, frame: bytes) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        for _ in range(READS):
            writer.write(frame)
            reply = await asyncio.wait_for(reader.readexactly(7), 5.0)
            assert reply[:3] == b"\x01\x03\x02"
    finally:
        writer.close()


def per_frame_objects() -> dict[str, int]:
    gc.collect()
    kinds = (FrameRecord, FrameEvent, _Waiting, ReadRequest, ReadResponse)
    counts = collections.Counter(type(o).__name__ for o in gc.get_objects() if isinstance(o, kinds))
    return {kind.__name__: counts[kind.__name__] for kind in kinds}


async def test_frames_served_leave_no_tracked_object_behind() -> None:
    base = load_profile()
    profile = dataclasses.replace(base, protocol=dataclasses.replace(base.protocol, turnaround_ms=0.5))
    servers = []
    before = per_frame_objects()  # what other tests left in this process
    try:
        for i in range(BUSES):
            sim = Simulator(profile, (1,), clock=RealtimeClock(), seed=i)
            server = Server(sim, ServeOptions(tcp="127.0.0.1:0", audit=True, bus_timing=True))
            await server.start()
            servers.append(server)
        frame = encode(ReadRequest(1, Reg.STATUS1, 1))
        await asyncio.gather(*(_poll(s.endpoints.tcp.port, frame) for s in servers))  # type: ignore[union-attr]
        after = per_frame_objects()
        left = {kind: after[kind] - before[kind] for kind in after}
        assert all(len(s.sim.bus.records) == 2 * READS for s in servers)  # every frame is in the rings
        # what waits in the line, the live audit's queue and the rings is bytes and numbers: at most the
        # objects of one transaction a bus (a request the line still names as its last) stay tracked
        assert all(count <= BUSES for count in left.values()), left
    finally:
        for server in servers:
            await server.aclose()
