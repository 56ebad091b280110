"""``c20sim drill``: play a plan of incidents on a running master, and judge how it came through, from the wire.

The runner serves one drive (realtime clock, bus timing on) on the transport asked for, starts the master
(``--master "CMD {tcp}"``, its placeholders filled with the endpoint) or waits for one already running,
watches its rhythm in a warm-up, keeps one reply off the wire to learn its timeout (the probe), then plays
each drill: the incident's steps (:mod:`c20sim.drill.incidents`) on the simulator's thread, its watch, the
plant made healthy again, a settle. Every frame is kept (bounded) and written with the run's marks to the frame
log; the verdicts are the pure judge's (:func:`c20sim.drill.judge`) over that log read back, so ``c20sim drill
--judge LOG --plan PLAN`` gives the same report offline.

Bad input (an unknown incident, a plan with an error, a placeholder for an endpoint not served, a master that
exits at once or never sends) is one line and exit 2; the master process (its process group) is always
stopped.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import os
import shlex
import signal
import subprocess
import tempfile
import threading
import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

from .control import causes, ops
from .core.bus import FrameRecord
from .core.simulator import Simulator
from .drill import Drill, Incident, Judgement, Learned, Mark, Plan, judge, learn, read_plan, standard_plan
from .drill.judge import marks_of, watch_seconds
from .drill.report import json_report, junit_xml, markdown, text_report
from .drive.profile import DEFAULT_PROFILE, Profile
from .traffic.auditlog import read_frames
from .transport.rows import Transport, find, rows
from .wire.errors import C20SimError

__all__ = [
    "MAX_RECORDS",
    "Handle",
    "RunOptions",
    "json_report",
    "judge_log",
    "junit_xml",
    "load_plan",
    "markdown",
    "marks_in",
    "play",
    "plot_timeline",
    "text_report",
]

#: The most frames a run keeps (a run of 3 minutes at 100 requests a second is 36,000); beyond, the run stops.
MAX_RECORDS = 400_000
#: The biggest plan file read.
MAX_PLAN = 256 * 1024
#: The biggest frame log --judge reads (the capture bound of c20sim audit).
MAX_LOG = 64 << 20
_POLL = 0.005


T = TypeVar("T")


class Handle(Protocol):
    """What the runner needs of a running simulator: its :class:`Simulator`, its profile, and a way to run a
    function on its thread between frames (:class:`c20sim.testing.C20Sim` is one)."""

    sim: Simulator
    profile: Profile

    def call(self, fn: Callable[..., T], *args: object) -> T: ...


@dataclass(frozen=True)
class RunOptions:
    plan: Plan
    transport: str = "tcp"
    master: str | None = None
    profile: str | Profile = DEFAULT_PROFILE
    drive: int = 1
    wait: float = 10.0
    log: str | None = None
    echo: Callable[[str], None] = lambda line: None
    #: set from another thread to stop the run (the drills played so far are judged)
    stop: threading.Event | None = None


class _Recorder:
    """The frames of the run, kept on the simulator's thread, bounded."""

    def __init__(self) -> None:
        self.records: list[FrameRecord] = []
        self.full = False
        self.requests = 0

    def __call__(self, record: FrameRecord) -> None:
        if len(self.records) >= MAX_RECORDS:
            self.full = True
            return
        self.records.append(record)
        if record.direction == "rx":
            self.requests += 1


class _Master:
    """The master process the drill started: its own process group, stopped on every way out."""

    def __init__(self, command: str, endpoints: Mapping[str, str]) -> None:
        try:
            text = command.format_map(_Strict(endpoints))
        except KeyError as exc:
            raise C20SimError(
                f"--master: placeholder {{{exc.args[0]}}} is not served here; use {', '.join('{' + k + '}' for k in endpoints)}"
            ) from None
        except (ValueError, IndexError) as exc:
            raise C20SimError(f"--master {command!r}: {exc} (write a literal brace as {{{{ or }}}})") from None
        try:
            argv = shlex.split(text)
        except ValueError as exc:
            raise C20SimError(f"--master {command!r}: {exc}") from None
        if not argv:
            raise C20SimError("--master: an empty command")
        self.command = text
        self.output = tempfile.TemporaryFile()  # noqa: SIM115 (closed in stop)
        try:
            self.process = subprocess.Popen(
                argv, stdin=subprocess.DEVNULL, stdout=self.output, stderr=subprocess.STDOUT, start_new_session=True
            )
        except OSError as exc:
            self.output.close()
            raise C20SimError(f"--master {argv[0]!r}: cannot start: {exc.strerror}") from None

    def exited(self) -> int | None:
        return self.process.poll()

    def last_words(self) -> str:
        self.output.seek(0)
        lines = [line for line in self.output.read()[-4096:].decode("utf-8", "replace").splitlines() if line.strip()]
        return lines[-1].strip() if lines else "no output"

    def stop(self) -> None:
        if self.process.poll() is None:
            for sig, wait in ((signal.SIGTERM, 3.0), (signal.SIGKILL, 3.0)):
                try:
                    os.killpg(self.process.pid, sig)
                except ProcessLookupError:
                    break
                try:
                    self.process.wait(wait)
                    break
                except subprocess.TimeoutExpired:
                    continue
        else:  # its children may live on in its group (a shell loop's mbpoll)
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.process.pid, signal.SIGKILL)
        self.output.close()


class _Strict(dict[str, str]):
    def __missing__(self, key: str) -> str:
        raise KeyError(key)


class _Run:
    """One drill run on a running simulator (``handle``), against the master at ``endpoints`` (started from
    ``options.master``, or already running)."""

    def __init__(self, options: RunOptions, handle: Handle, endpoints: Mapping[str, str]) -> None:
        self.options = options
        self.plan = options.plan
        self.marks: list[Mark] = []
        self.recorder = _Recorder()
        self.master: _Master | None = None
        self.sim: Handle | None = handle
        self.endpoints = endpoints
        self.stopped_early = ""

    # -- on the simulator's thread

    def _at(self, fn: Callable[[Simulator], object]) -> float:
        """Run ``fn`` on the simulator's thread, between frames; returns the frames' clock just after."""
        assert self.sim is not None

        def act() -> float:
            assert self.sim is not None
            fn(self.sim.sim)
            return time.perf_counter()

        return self.sim.call(act)

    def _mark(self, event: str, index: int = 0, incident: str = "", t: float | None = None) -> float:
        at = t if t is not None else self._at(lambda sim: None)
        self.marks.append(Mark(at, event, index, incident))
        return at

    def _requests(self) -> int:
        assert self.sim is not None
        return self.sim.call(lambda: self.recorder.requests)

    def _alive(self) -> bool:
        if self.options.stop is not None and self.options.stop.is_set():
            self.stopped_early = self.stopped_early or "stopped"
            return False
        if self.master is None:
            return True
        code = self.master.exited()
        if code is not None and not self.stopped_early:
            self.stopped_early = f"the master exited (code {code}): {self.master.last_words()}"
        return code is None

    def _sleep(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and self._alive():
            time.sleep(min(0.05, max(0.0, end - time.monotonic())))

    # -- the steps

    def _step(self, op: str, args: Mapping[str, object]) -> Callable[[Simulator], object]:
        drive = self.options.drive
        if op == "link":
            return lambda sim: ops.set_link_faults(sim, None, args)
        if op == "clear-link":
            return lambda sim: ops.clear_link_faults(sim, None)
        if op == "trip":
            return lambda sim: causes.trip(sim, drive, args["cause"])
        if op == "release":
            return lambda sim: causes.release(sim, drive, args["cause"])
        if op == "fcode":
            return lambda sim: ops.keypad_edit(sim, drive, str(args["code"]), args["value"])
        if op == "power-off":
            return lambda sim: ops.set_link_faults(sim, None, {"offline": True})

        def power_on(sim: Simulator) -> None:
            ops.power_cycle(sim, drive)
            ops.clear_link_faults(sim, None)

        if op == "power-on":
            return power_on
        raise AssertionError(op)

    def _restore(self, sim: Simulator) -> None:
        """The plant healthy again between drills: no link fault, no cause, no fault held."""
        ops.clear_link_faults(sim, None)
        causes.clear_all(sim, self.options.drive)
        if ops.held_fault(sim, self.options.drive):
            ops.clear_fault(sim, self.options.drive, reset=True)

    def _link(self, name: str) -> int:
        """A count of the bus's link faults (``replies``, ``drop_next``), read on the simulator's thread."""
        assert self.sim is not None
        sim = self.sim.sim
        value = self.sim.call(lambda: getattr(sim.link_faults(None), name))
        return int(value)

    def _replies_left(self) -> int:
        return self._link("replies")

    def _play(self, drill: Drill, learned: Learned) -> None:
        steps, length = drill.incident.steps(drill.values, learned)
        start: float | None = None
        t = 0.0
        begun = time.monotonic()
        for step in steps:
            due = begun + step.at
            while time.monotonic() < due and self._alive():
                time.sleep(min(0.01, max(0.0, due - time.monotonic())))
            t = self._at(self._step(step.op, step.args))
            if start is None:
                start = t
                self._mark("start", drill.index, drill.name, t)
        assert start is not None
        if length is None:  # a reply fault: until its replies are spent
            limit = time.monotonic() + max(10.0, 20 * learned.timeout)
            while self._replies_left() > 0 and time.monotonic() < limit and self._alive():
                time.sleep(_POLL)
            end = self._at(lambda sim: ops.clear_link_faults(sim, None))
        else:
            end = t  # every timed incident ends with a step at its length (release, link back, power on)
        self._mark("end", drill.index, drill.name, end)
        self._sleep(watch_seconds(drill, learned))
        self._mark("watched", drill.index, drill.name)
        self._at(self._restore)
        self._sleep(self.plan.settle)

    # -- the run

    def frames(self) -> list[tuple[float, str, bytes]]:
        assert self.sim is not None
        records = self.sim.call(lambda: list(self.recorder.records))
        lines = "".join(json.dumps(r.as_dict()) + "\n" for r in records)
        return list(read_frames(io.StringIO(lines), "the run"))

    def run(self) -> Judgement:
        """Play the plan; the judgement over every frame of the run (the frame log's, when one is written)."""
        options = self.options
        assert self.sim is not None
        bus = self.sim.sim.bus
        unsubscribe = self.sim.call(lambda: bus.subscribe(self.recorder))
        try:
            keys = {row.key for row in rows()}  # the transports' ready-file keys (not {host}, {port}, {KEY_port})
            where = ", ".join(f"{k} {v}" for k, v in self.endpoints.items() if k in keys)
            if options.master is not None:
                self.master = _Master(options.master, self.endpoints)
                options.echo(f"drill: master started: {self.master.command}")
            else:
                options.echo(f"drill: waiting for a master on {where or 'the served ports'}")
            self._first_request(where or "the served ports")
            self._drills()
        finally:
            if self.master is not None:
                self.master.stop()
            self.sim.call(unsubscribe)
            self.sim.call(lambda: self._restore(self.sim.sim) if self.sim else None)
            lines = self._lines()
        if options.log is not None:
            write_file(options.log, "".join(line + "\n" for line in lines).encode(), "--log")
        return _judge_lines(lines, self.plan, self.sim.profile)

    def _lines(self) -> list[str]:
        """The frame log: a header, then every frame and mark of the run in time order, as JSON lines."""
        assert self.sim is not None
        records = self.sim.call(lambda: list(self.recorder.records))
        items: list[tuple[float, str]] = [(r.t, json.dumps(r.as_dict())) for r in records]
        items += [(m.t, json.dumps(m.as_dict())) for m in self.marks]
        items.sort(key=lambda item: item[0])
        header = json.dumps({"kind": "drill-plan", "plan": self.plan.name, "seed": self.plan.seed})
        return [header, *(line for _, line in items)]

    def _first_request(self, where: str) -> None:
        limit = time.monotonic() + self.options.wait
        while self._requests() == 0:
            if self.options.stop is not None and self.options.stop.is_set():
                self.stopped_early = "stopped"
                return
            if self.master is not None and self.master.exited() is not None:
                raise C20SimError(
                    f"--master: exited at once (code {self.master.exited()}) before sending anything: "
                    f"{self.master.last_words()}"
                )
            if time.monotonic() > limit:
                raise C20SimError(f"the master sent nothing in {self.options.wait:g} s on {where} (--wait)")
            time.sleep(0.02)

    def _drills(self) -> None:
        plan = self.plan
        self._mark("warmup")
        self._sleep(plan.warmup)
        given = Learned(plan.poll_period, plan.timeout, 0.0, True) if plan.poll_period and plan.timeout else None
        self._mark("probe")
        if given is None and self._alive():  # stopped (DELETE /drill) or the master gone: no fault, not the probe
            before = self._requests()
            self._at(lambda sim: ops.set_link_faults(sim, None, {"drop_next": 1}))
            limit = time.monotonic() + 30.0
            while time.monotonic() < limit and self._alive():
                if self._link("drop_next") == 0 and self._requests() >= before + 2:
                    break
                time.sleep(_POLL)
        self._mark("learned")
        try:
            learned = learn(self.frames(), self.marks, given)
        except ValueError:
            return  # the judgement says why
        self.options.echo(
            f"drill: the master polls every {learned.period * 1000:.0f} ms, {learned.rate:.1f} requests/s, "
            f"times out after {learned.timeout * 1000:.0f} ms"
        )
        for drill in plan.drills:
            if not self._alive() or self.recorder.full:
                break
            self._play(drill, learned)
            self.options.echo(f"drill: {drill.label} played")


def play(handle: Handle, options: RunOptions, endpoints: Mapping[str, str] | None = None) -> tuple[Judgement, str]:
    """Play ``options.plan`` on the running simulator ``handle`` (the clock realtime); (the judgement, why the run
    ended early or "")."""
    if handle.sim.virtual:
        raise C20SimError("a drill needs the realtime clock: the master keeps its own time (clock='realtime')")
    run = _Run(options, handle, endpoints or {})
    judgement = run.run()
    return judgement, run.stopped_early


class _LoopHandle:
    """A served simulator seen from a worker thread: each call runs on the serving loop, between frames."""

    def __init__(self, sim: Simulator, loop: asyncio.AbstractEventLoop) -> None:
        self.sim, self.profile, self.loop = sim, sim.profile, loop

    def call(self, fn: Callable[..., T], *args: object) -> T:
        async def run() -> T:
            return fn(*args)

        return asyncio.run_coroutine_threadsafe(run(), self.loop).result(30.0)


def drill_transports() -> tuple[str, ...]:
    """The transports a drill can be played over, from the rows (:mod:`c20sim.transport.rows`): those the test
    handle can open (a row's ``fixture``), usable here (a pty needs POSIX); ``c20sim drill --transport``'s choices."""
    return tuple(row.name for row in rows() if row.fixture is not None and row.usable())


def carries(incident: Incident, transport: str) -> bool:
    """Whether ``incident`` can be played over ``transport``: the incident names it, or names a transport of the
    same line model (a new RTU transport carries what RTU over TCP does)."""
    if transport in incident.transports:
        return True
    row = find(transport)
    return row is not None and any((o := find(n)) is not None and o.model == row.model for n in incident.transports)


def _kept(plan: Plan, served: Sequence[str]) -> Plan:
    """``plan`` with only the drills one of ``served`` carries, numbered again."""
    kept = [d for d in plan.drills if any(carries(d.incident, t) for t in served)]
    drills = tuple(Drill(i, d.incident, d.values) for i, d in enumerate(kept, 1))
    return Plan(plan.name, plan.seed, plan.warmup, plan.settle, drills, plan.poll_period, plan.timeout)


def standard_for(seed: int, transport: str | None) -> Plan:
    """The standard plan; for ``transport`` (a transport row's name), only the incidents it carries."""
    plan = standard_plan(seed)
    return plan if transport is None else _kept(plan, (transport,))


def serve_runner(
    sim: Simulator, loop: asyncio.AbstractEventLoop, served: Sequence[Transport] = ()
) -> Callable[[Mapping[str, Any], Callable[[str], None], threading.Event], dict[str, Any]]:
    """The drill runner ``serve`` gives its simulator (:mod:`c20sim.control.drills`): a request's plan played on
    the master that polls the serve, in the calling (worker) thread; the report as JSON. ``served``: the transport
    rows serve opened (none: RTU over TCP's): the standard plan keeps what one of them carries, and a drill none
    can carry is refused."""
    names = tuple(row.name for row in served) or ("tcp",)

    def run(fields: Mapping[str, Any], progress: Callable[[str], None], stop: threading.Event) -> dict[str, Any]:
        seed = int(fields.get("seed") or 1)
        items = fields.get("plan")
        if items is None:
            plan = _kept(standard_plan(seed), names)
        else:
            drills = [{"incident": item} if isinstance(item, str) else dict(item) for item in items]
            doc: dict[str, object] = {"seed": seed, "drill": drills}
            for key in ("warmup", "poll_period", "timeout"):
                if fields.get(key) is not None:
                    doc[key] = fields[key]
            plan = read_plan(doc, "POST /drill")
            for d in plan.drills:
                if not any(carries(d.incident, t) for t in names):
                    raise C20SimError(
                        f"POST /drill: drill {d.index}: {d.name} cannot be played over {', '.join(names)} "
                        f"(only {', '.join(d.incident.transports)}): a gateway forwards no broken reply"
                    )
        options = RunOptions(
            plan, profile=sim.profile, wait=float(fields.get("wait") or 60.0), echo=progress, stop=stop
        )
        judgement, early = play(_LoopHandle(sim, loop), options)
        report: dict[str, Any] = json.loads(json_report(judgement, early))
        report["text"] = text_report(judgement, early)
        return report

    return run


def _judge_lines(lines: Sequence[str], plan: Plan, profile: Profile, where: str = "the run") -> Judgement:
    """The judgement of a drill's frame log, given as its lines: the live run's and --judge's one path."""
    frames = list(read_frames(io.StringIO("".join(line + "\n" for line in lines)), where))
    marks = marks_of(json.loads(line) for line in lines if line.startswith('{"kind": "drill"'))
    if not marks:
        raise C20SimError(f"{where}: no drill marks; give the frame log a c20sim drill run wrote (--log)")
    played = {(m.index, m.incident) for m in marks if m.event == "start"}
    planned = {(d.index, d.name) for d in plan.drills}
    if not played <= planned:
        index, name = sorted(played - planned)[0]
        raise C20SimError(f"{where}: drill {index} {name} was played but is not in {plan.name}; give the run's plan")
    return judge(frames, plan, marks, turnaround=profile.protocol.turnaround_ms / 1000.0)


def marks_in(path: str) -> tuple[list[tuple[float, str, bytes]], list[Mark]]:
    """The frames and the marks of the drill's frame log at ``path``."""
    lines = _read_log(path)
    frames = list(read_frames(io.StringIO("".join(line + "\n" for line in lines)), path))
    return frames, marks_of(json.loads(line) for line in lines if line.startswith('{"kind": "drill"'))


def _read_log(path: str) -> list[str]:
    try:
        if not os.path.isfile(path):
            raise C20SimError(f"--judge {path}: not a regular file")
        if os.path.getsize(path) > MAX_LOG:
            raise C20SimError(f"--judge {path}: bigger than {MAX_LOG >> 20} MiB")
        with open(path, encoding="utf-8", errors="replace") as stream:
            return stream.read().splitlines()
    except OSError as exc:
        raise C20SimError(f"--judge {path}: cannot read: {exc.strerror}") from None


def judge_log(path: str, plan: Plan, profile: Profile) -> Judgement:
    """The judgement of a drill's frame log at ``path`` against ``plan``, offline."""
    return _judge_lines(_read_log(path), plan, profile, path)


def plot_timeline(frames: Sequence[tuple[float, str, bytes]], marks: Sequence[Mark], path: str) -> bool:
    """A PNG of the run: each request (retries in red) and each incident's span; False without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    t0 = min((m.t for m in marks), default=frames[0][0] if frames else 0.0)
    requests = [(t - t0, data) for t, d, data in frames if d == "rx"]
    retried = [t for (t, data), (_, before) in zip(requests[1:], requests, strict=False) if data == before]
    fig, ax = plt.subplots(figsize=(12, 3))
    ax.vlines([t for t, _ in requests], 0, 1, color="0.6", linewidth=0.5, label="request")
    ax.vlines(retried, 0, 1, color="red", linewidth=0.8, label="same request again")
    starts = {m.index: m for m in marks if m.event == "start"}
    for m in marks:
        if m.event == "end" and m.index in starts:
            s = starts[m.index].t - t0
            ax.axvspan(s, max(m.t - t0, s + 0.05), color="orange", alpha=0.3)
            ax.text(s, 1.02, m.incident, rotation=60, fontsize=7)
    ax.set_xlabel("seconds")
    ax.set_yticks([])
    ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def load_plan(path: str | None, seed: int | None, transport: str | None) -> Plan:
    """The plan at ``path`` (a TOML file), or the standard plan for ``transport``; one-line errors."""
    if path is None:
        return standard_for(seed if seed is not None else 1, transport)
    try:
        if not os.path.isfile(path):
            raise C20SimError(f"--plan {path}: not a regular file")
        if os.path.getsize(path) > MAX_PLAN:
            raise C20SimError(f"--plan {path}: bigger than {MAX_PLAN // 1024} KiB; not a plan")
        with open(path, "rb") as stream:
            doc = tomllib.load(stream)
    except OSError as exc:
        raise C20SimError(f"--plan {path}: cannot read: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise C20SimError(f"{path}: not TOML: {exc}") from None
    plan = read_plan(doc, path)
    if seed is not None:
        plan = Plan(plan.name, seed, plan.warmup, plan.settle, plan.drills, plan.poll_period, plan.timeout)
    if transport is not None:
        for d in plan.drills:
            if not carries(d.incident, transport):
                raise C20SimError(
                    f"{path}: drill {d.index}: {d.name} cannot be played over {transport} "
                    f"(only {', '.join(d.incident.transports)}): a gateway forwards no broken reply"
                )
    return plan


def write_file(path: str, data: bytes, option: str) -> None:
    try:
        with open(path, "wb") as out:
            out.write(data)
    except OSError as exc:
        raise C20SimError(f"{option} {path}: cannot write: {exc.strerror}") from None
