"""``c20sim dashboard``: the drive on the bench, in a terminal: see it, work it, break it.

The dashboard is a client of a served simulator's control API (``c20sim serve
--control``, in a process of its own): it never holds a simulator, so nothing
it draws can hold a reply on the wire. What it shows comes from the API's
``/stream`` WebSocket (telemetry at ``refresh_hz``, frame records as they
happen, in one merged :class:`TelemetryUpdated` and :class:`FramesLogged`);
everything done to a drive is one API call through the
:class:`~c20sim.tui.workbench.Workbench` over
:class:`~c20sim.control.client.RemoteOps`. A refused call (or a server gone)
is shown as a notification, never a traceback. Closing the dashboard leaves
the server alone: ``c20sim dashboard`` stops the one it started itself.

The tabs below the plots are the rows of :mod:`c20sim.tui.tabs`: the tab bar,
the keys that switch to them, the panel kept up to date, the drive pushed down
to the panels that act on one, the focus, the help and the palette iterate them.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from platformdirs import user_downloads_path
from rich.text import Text
from textual import on
from textual.app import ComposeResult, ScreenStackError, SystemCommand
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.css.query import NoMatches
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import Footer, OptionList, TabbedContent, TabPane
from textual.widgets.option_list import Option

from ..control import routes
from ..control.client import RemoteOps
from ..control.ops import ControlError
from ..wire.errors import C20SimError
from ..wire.registers import RUN_CHANNELS
from .keys import KeysInTurn
from .messages import ConditionsChanged, SaveLogRequested, TelemetryUpdated
from .screens import HelpScreen, SaveLogScreen
from .status import STATUS_STYLES, DriveStatus, TitleBar, TrendPlot, clock_forms
from .tabs import tabs
from .widgets import (
    DeviceFaultsPanel,
    FrameLog,
    LinkFaultsPanel,
    record_from_dict,
)
from .workbench import LINK_SWITCHES, DriveView, Workbench

__all__ = ["Dashboard"]

T = TypeVar("T")

#: Frames the server keeps waiting for the dashboard's log, and how often it sends them: beyond 40 frames a batch,
#: 5 batches a second (more than anyone reads as they scroll) it skips them and says how many. A busy bus costs the
#: server and the dashboard at most that.
STREAM_BUFFER = 40
FRAME_HZ = 5

#: From this width on the footer shows the clock's second keys too (``<``/``>`` on a realtime clock, ``T`` on a
#: virtual one); below it they would push ``q Quit`` off an 80-column footer, and the help (``?``, F1) lists them.
FOOTER_WIDE = 100


class MainScreen(Screen[None]):
    """The drive, its trends, and the bench panels."""

    def __init__(self, bench: Workbench) -> None:
        super().__init__()
        self.bench = bench

    def compose(self) -> ComposeResult:
        bench = self.bench
        s, p, m = bench.profile.supply, bench.profile.protection, bench.profile.motor
        yield TitleBar(id="title")
        with Horizontal(id="top"):
            drives = OptionList(*[Option(str(a), id=str(a)) for a in bench.addresses], id="drives")
            drives.display = len(bench.addresses) > 1
            yield drives
            yield DriveStatus(id="status")
            with Vertical(id="plots"):
                yield TrendPlot("speed", "rpm", m.rated_speed_rpm, id="plot-speed")
                yield TrendPlot("current", "A", p.current_limit_a, digits=2, id="plot-current")
                yield TrendPlot("bus", "V", s.overvoltage_v, digits=1, id="plot-bus")
        rows = list(tabs())
        with TabbedContent(id="tabs", initial=rows[0].id):
            for tab in rows:
                with TabPane(tab.label, id=tab.id):
                    yield tab.panel(bench, id=tab.panel_id)
        yield Footer()

    def on_mount(self) -> None:
        app = self.app
        assert isinstance(app, Dashboard)
        app.attached(self)

    def on_resize(self) -> None:
        self.app.refresh_bindings()  # the footer's clock keys follow the width (FOOTER_WIDE)


class Dashboard(KeysInTurn):
    """The c20sim dashboard of the simulator served at ``remote``'s control API."""

    CSS_PATH = "dashboard.tcss"
    TITLE = "c20sim"
    ENABLE_COMMAND_PALETTE = True

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("f", "keypad('fwd')", "Fwd"),
        Binding("r", "keypad('rev')", "Rev"),
        Binding("s", "keypad('stop')", "Stop"),
        Binding("j", "keypad('jog')", "Jog"),
        Binding("J", "keypad('jogrev')", "Jog rev", show=False),
        Binding("x", "keypad('reset')", "Reset"),
        Binding("m", "channel", "Channel", show=False),
        Binding("S", "speed_source", "Speed source", show=False),
        # The clock's keys, in the footer on the clock they act on (check_action); those marked 'wide' only where the
        # footer has room for them (FOOTER_WIDE), the key working all the same through its hidden twin below it.
        Binding("p", "pause", "Pause"),
        Binding("less_than_sign", "clock_speed(0.5, 'wide')", "Slower"),
        Binding("less_than_sign", "clock_speed(0.5)", "Clock slower", show=False),
        Binding("greater_than_sign", "clock_speed(2, 'wide')", "Faster"),
        Binding("greater_than_sign", "clock_speed(2)", "Clock faster", show=False),
        Binding("plus", "keypad_speed(1)", "Speed +", show=False),
        Binding("minus", "keypad_speed(-1)", "Speed -", show=False),
        Binding("P", "power_cycle", "Power cycle", show=False),
        Binding("D", "restore_defaults", "Defaults", show=False),
        Binding("t", "advance(1)", "+1s"),
        Binding("T", "advance(10, 'wide')", "+10s"),
        Binding("T", "advance(10)", "+10s", show=False),
        Binding("left_square_bracket", "drive(-1)", "Prev drive", show=False),
        Binding("right_square_bracket", "drive(1)", "Next drive", show=False),
        Binding("question_mark", "help", "Help"),
        Binding("f1", "help", "Help", show=False),  # the usual help key of terminal programs (the footer shows ?)
        Binding("q", "quit", "Quit"),
    ]

    selected = reactive(0)

    def __init__(self, remote: RemoteOps, *, refresh_hz: float = 5.0) -> None:
        super().__init__()
        for tab in tabs():  # one key per tab row, bound when the dashboard is made
            # a priority key: taken, and the tab's focus moved, before the keys behind it in a burst (a paste, a
            # tmux send-keys) are passed on, so they reach the tab's field and not the one it left
            self._bindings.bind(tab.key, f"tab('{tab.id}')", tab.title, show=False, priority=True)
        self.remote = remote
        self.bench = Workbench(remote)
        self.refresh_hz = refresh_hz
        self.error: C20SimError | None = None
        self.views: dict[int, DriveView] = {}
        self._plotted: tuple[int, int] | None = None
        self._drive_labels: dict[int, str] = {}
        self.set_reactive(Dashboard.selected, next(iter(self.bench.addresses)))
        #: whether the stream is connected now; telemetry messages taken from it so far
        self.streaming = False
        self.received = 0
        self._stream_task: asyncio.Task[None] | None = None
        self._signals: list[int] = []
        #: the server's notices already shown (it keeps a few, each said once)
        self._notices_shown: set[str] = set()

    # --- life cycle

    def get_default_screen(self) -> Screen[None]:
        return MainScreen(self.bench)

    def attached(self, screen: MainScreen) -> None:
        """Start reading the stream (from the main screen's mount, once its widgets exist)."""
        self.watch_selected(self.selected)
        self._show_title(screen)
        screen.query_one(FrameLog).focus()
        self._stream_task = asyncio.create_task(self._read_stream(screen.query_one(FrameLog)))
        loop = asyncio.get_running_loop()
        # a kill: close as q does, so the server it started is stopped too (the terminal gone: session.served)
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError, AttributeError):
            loop.add_signal_handler(signal.SIGTERM, self.exit)
            self._signals.append(signal.SIGTERM)
        self.refresh_views()

    async def on_unmount(self) -> None:
        self.stop_keys()
        loop = asyncio.get_running_loop()
        for sig in self._signals:
            loop.remove_signal_handler(sig)
        self._signals.clear()
        if self._stream_task is not None:
            self._stream_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await asyncio.wait_for(self._stream_task, 2.0)  # a server that does not answer the close: not long
        self.remote.client.close()

    async def _read_stream(self, framelog: FrameLog) -> None:
        """Telemetry and frames from the server's stream, until the dashboard closes; reconnects if it drops."""
        import aiohttp  # the API's own WebSocket client

        client = self.remote.client
        url = f"{client.url}{routes.table().named('stream').path}?hz={self.refresh_hz:g}&frame_hz={FRAME_HZ}&buffer={STREAM_BUFFER}"
        lost = False
        async with aiohttp.ClientSession(headers=client.headers()) as session:
            while True:
                try:
                    close = aiohttp.ClientWSTimeout(ws_close=1.0)
                    async with session.ws_connect(url, heartbeat=10.0, max_msg_size=0, timeout=close) as ws:
                        self._stream_state(True, lost)
                        async for message in ws:
                            if message.type is aiohttp.WSMsgType.TEXT:
                                self._take(json.loads(message.data), framelog)
                            elif message.type is aiohttp.WSMsgType.ERROR:
                                break
                except (aiohttp.ClientError, OSError, ValueError):
                    pass
                if self.streaming or not lost:
                    self._stream_state(False, lost)
                lost = True
                await asyncio.sleep(1.0)

    def _stream_state(self, up: bool, was_lost: bool) -> None:
        self.streaming = up
        if up and was_lost:
            self.notify(f"attached again to {self.remote.client.url}", timeout=3)
        elif not up:
            self.notify(
                f"lost the server at {self.remote.client.url}; trying again every second", severity="error", timeout=5
            )
        with contextlib.suppress(NoMatches, LookupError):
            self._show_title(self.get_screen_main())

    def _take(self, data: dict[str, Any], framelog: FrameLog) -> None:
        kind = data.get("type")
        if kind == "telemetry":
            self.received += 1
            self._show_notices(data.get("notices"))
            if self.remote.update(data):
                self.refresh_views()
            framelog.show_log_dropped(int(data.get("log_dropped", 0)))
        elif kind == "frames":
            missed = int(data.get("missed", 0))
            for record in data["frames"]:
                framelog.add(record_from_dict(record), missed)
                missed = 0

    def _show_notices(self, notices: object) -> None:
        """What the server has to say about the way a master talks to it (a Modbus TCP master on the RTU port):
        each notice once, for long enough to read."""
        if not isinstance(notices, list):
            return
        for text in notices:
            if isinstance(text, str) and text not in self._notices_shown:
                self._notices_shown.add(text)
                self.notify(text, title="the server says", severity="warning", timeout=30)

    def _show_title(self, screen: MainScreen) -> None:
        """The title bar: where a master connects, how the clock runs, the profile, and ``server lost`` while it is
        (fitted to the bar's width by :func:`~c20sim.tui.status.title_line`)."""
        lost = self._stream_task is not None and not self.streaming
        screen.query_one(TitleBar).show(self.connect_text(), self.clock_forms(), self.bench.profile.name, lost)

    def clock_forms(self) -> tuple[str, str, str]:
        """The model's time and how the clock runs, long to short: ``t 12.3 s ×1 realtime paused`` ..."""
        snapshot = self.remote.latest
        t = float(snapshot.get("t", 0.0))
        speed = snapshot.get("speed")
        return clock_forms(
            t, self.bench.virtual, float(speed) if speed is not None else 1.0, bool(snapshot.get("paused"))
        )

    def connect_text(self) -> str:
        """Where a master connects: every endpoint the server has, in its transport rows' order, each by its word
        here or else by its ready-file key (a transport row added later is shown by its key, never left out)."""
        names = {"tcp": "RTU/TCP", "modbus_tcp": "Modbus TCP"}
        parts = [f"{names.get(key, key)} {address}" for key, address in self.remote.endpoints.items()]
        return " · ".join(parts) if parts else "no endpoint (not serving)"

    # --- refreshing

    def refresh_views(self) -> None:
        """Post the drives' views from the latest telemetry (merged if the UI is behind)."""
        self.post_message(TelemetryUpdated(self.bench.sample()))

    def _call(self, action: Callable[[], T]) -> T | None:
        """Run one bench action; a refusal or a server gone is a notification. None if it failed."""
        try:
            return action()
        except ControlError as exc:
            self.notify(f"drive {self.selected}: {exc}", severity="error", timeout=5)
            return None

    def on_telemetry_updated(self, message: TelemetryUpdated) -> None:
        self.views = message.views
        self._show()

    def on_conditions_changed(self, message: ConditionsChanged) -> None:
        if message.note:
            self.notify(message.note, timeout=3)
        self.refresh_views()

    def _show(self) -> None:
        # shutting down: the widgets are gone (NoMatches), or the screens too, with telemetry still queued
        with contextlib.suppress(NoMatches, ScreenStackError):
            self._show_views()

    def _show_views(self) -> None:
        screen = self.screen if isinstance(self.screen, MainScreen) else None
        if screen is None:
            try:
                screen = self.get_screen_main()
            except LookupError:
                return
        view = self.views.get(self.selected)
        if view is None:
            return
        screen.query_one(DriveStatus).view = view
        self._show_title(screen)
        history = self.bench.history[self.selected]
        plotted = (self.selected, history.samples)
        if plotted != self._plotted:  # the plots move on with each sample (2 a second), not each refresh
            self._plotted = plotted
            screen.query_one("#plot-speed", TrendPlot).values = tuple(history.speed)
            screen.query_one("#plot-current", TrendPlot).values = tuple(history.current)
            screen.query_one("#plot-bus", TrendPlot).values = tuple(history.bus)
        drives = screen.query_one("#drives", OptionList)
        if drives.display:
            for index, (address, each) in enumerate(self.views.items()):
                status = each.telemetry.status
                label = Text(f"{address} ", style="bold")
                label.append(f"{each.telemetry.state[:9]}", style=STATUS_STYLES.get(status, ""))
                label.no_wrap = True
                if self._drive_labels.get(address) != label.plain + str(status):
                    self._drive_labels[address] = label.plain + str(status)
                    drives.replace_option_prompt_at_index(index, label)
        active = tabs().get(screen.query_one(TabbedContent).active)  # only the panel on show is kept up to date
        if active is not None and active.refresh is not None:
            active.refresh(screen.query_one(f"#{active.panel_id}"), self.selected)

    def get_screen_main(self) -> MainScreen:
        for screen in self.screen_stack:
            if isinstance(screen, MainScreen):
                return screen
        raise LookupError("no main screen")

    # --- actions

    def action_keypad(self, key: str) -> None:
        refused = self._call(lambda: self.bench.keypad(self.selected, key) or "")
        if refused:
            self.notify(refused, severity="warning", timeout=4)
        self.refresh_views()

    def action_channel(self) -> None:
        channel = self._call(lambda: self.bench.cycle_channel(self.selected))
        if channel is not None:
            self.notify(f"drive {self.selected}: run channel {RUN_CHANNELS[channel]} (F00.01 = {channel})", timeout=3)
        self.refresh_views()

    def action_speed_source(self) -> None:
        try:
            words = self.bench.cycle_speed_source(self.selected)
        except C20SimError as exc:
            self.notify(f"drive {self.selected}: {exc}", severity="warning", timeout=4)
            return
        self.notify(f"drive {self.selected}: speed from {words} (F00.02)", timeout=3)
        self.refresh_views()

    def action_keypad_speed(self, steps: int) -> None:
        words = self.bench.step_keypad_speed(self.selected, int(steps))
        self.notify(f"drive {self.selected}: keypad speed {words} (F00.10)", timeout=2)
        self.refresh_views()

    def action_power_cycle(self) -> None:
        def cycle() -> bool:
            self.bench.power_cycle(self.selected)
            return True

        if self._call(cycle):
            self.notify(f"drive {self.selected}: power cycled", timeout=3)
        self.refresh_views()

    def action_restore_defaults(self) -> None:
        refused = self._call(lambda: self.bench.restore_defaults(self.selected) or "")
        if refused is None:
            pass  # already said
        elif refused:
            self.notify(refused, severity="warning", timeout=4)
        else:
            self.notify(f"drive {self.selected}: default parameters restored", timeout=3)
        self.refresh_views()

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        # A key that does nothing on this clock is not offered (False hides it from the footer; None would
        # show it greyed out, still there to be tried)
        if action == "advance" and not self.bench.virtual:
            return False  # a realtime clock is not advanced by hand
        if action in ("pause", "clock_speed") and self.bench.virtual:
            return False  # a virtual clock stands still until advanced (t / T)
        if "wide" in parameters and self.size.width < FOOTER_WIDE:
            return False  # the footer has no room: its hidden twin takes the key
        if action == "tab" and not isinstance(self.screen, MainScreen):
            return False  # the help, the palette, the save question: not a tab switched behind them
        if action == "drive" and len(self.bench.addresses) < 2:
            return None
        return True

    def action_advance(self, seconds: float, _where: str = "") -> None:
        def advance() -> bool:
            self.bench.advance(float(seconds))
            return True

        if self._call(advance):
            self.notify(f"virtual time +{float(seconds):g} s: t = {self.remote.now():.1f} s", timeout=2)
        self.refresh_views()

    def action_drive(self, step: int) -> None:
        addresses = list(self.bench.addresses)
        self.selected = addresses[(addresses.index(self.selected) + step) % len(addresses)]
        self.get_screen_main().query_one("#drives", OptionList).highlighted = addresses.index(self.selected)

    @on(OptionList.OptionHighlighted, "#drives")
    def _drive_chosen(self, event: OptionList.OptionHighlighted) -> None:
        if event.option.id is not None:
            self.selected = int(event.option.id)

    def watch_selected(self, address: int) -> None:
        with contextlib.suppress(NoMatches, LookupError):  # push the drive down to the panels that act on it
            screen = self.get_screen_main()
            for tab in tabs():
                if tab.follows_drive:
                    panel: Any = screen.query_one(f"#{tab.panel_id}")
                    panel.selected = address
        if self.views:
            self._show()

    @on(SaveLogRequested)
    def _save_requested(self) -> None:
        self.action_save_log()

    def action_tab(self, tab: str) -> None:
        screen = self.get_screen_main()
        screen.query_one(TabbedContent).active = tab
        self._show()  # fill the tab's fields now: a value arriving later would write over what is typed next
        self._focus_tab(tab)

    @on(TabbedContent.TabActivated)
    def _tab_activated(self, event: TabbedContent.TabActivated) -> None:
        with contextlib.suppress(LookupError):  # closing: the screens are gone
            focused = self.get_screen_main().focused
            if event.pane.id is not None and (focused is None or event.pane not in focused.ancestors_with_self):
                self._show()  # a tab clicked: fill its fields before one takes the focus
                self._focus_tab(event.pane.id)

    def _focus_tab(self, tab: str) -> None:
        row = tabs()[tab]
        screen = self.get_screen_main()
        # now, not later (Widget.focus): the next key of a burst is passed on to the widget focused when it is read
        screen.set_focus(screen.query_one(row.focus or f"#{row.panel_id}"))

    def action_pause(self) -> None:
        """The realtime clock: pause it, or resume it (the model stands still meanwhile; the wire still answers)."""
        paused = bool(self.remote.latest.get("paused"))
        state = self._call(lambda: self.bench.ops.call("resume" if paused else "pause"))
        if state is not None:
            self.notify("clock " + ("paused: the model stands still" if state["paused"] else "running"), timeout=3)

    def action_clock_speed(self, factor: float, _where: str = "") -> None:
        speed = float(self.remote.latest.get("speed") or 1.0) * float(factor)
        state = self._call(lambda: self.bench.ops.call("set_speed", speed=speed))
        if state is not None:
            self.notify(f"clock ×{float(state['speed']):g}", timeout=2)

    def action_reset_setup(self) -> None:
        """Every drive back to the profile's defaults, as at start (the server keeps running)."""
        if self._call(lambda: self.bench.ops.call("reset")) is not None:
            self.notify("every drive reset to the profile's defaults", timeout=3)
        self.refresh_views()

    def action_screenshot(self, filename: str | None = None, path: str | None = None) -> None:
        """Textual's screenshot, into ~/Downloads where it exists, else the current directory (Textual's own
        default fails, and says only that, on a machine with no Downloads folder)."""
        if path is None:
            downloads = user_downloads_path()
            path = str(downloads if downloads.is_dir() else Path.cwd())
        self.deliver_screenshot(filename, path)

    def action_help(self) -> None:
        self.push_screen(HelpScreen())

    def action_save_log(self) -> None:
        def save(path: str | None) -> None:
            if path is None:
                return
            try:
                count = self.get_screen_main().query_one(FrameLog).save(Path(path))
            except OSError as exc:
                self.notify(f"cannot save to {path}: {exc.strerror}", severity="error")
                return
            self.notify(f"saved {count} frames to {path}", timeout=4)

        self.push_screen(SaveLogScreen("c20sim-frames.log"), save)

    # --- the command palette

    def get_system_commands(self, screen: Screen[object]) -> Iterable[SystemCommand]:
        yield from super().get_system_commands(screen)
        for key, name in (
            ("fwd", "RUN forward"),
            ("rev", "RUN reverse"),
            ("jog", "JOG"),
            ("stop", "STOP"),
            ("reset", "RESET"),
        ):
            yield SystemCommand(f"Keypad: {name}", "press the drive's keypad key", lambda k=key: self.action_keypad(k))
        yield SystemCommand("Run channel: next", "F00.01 keypad/terminals/communication", self.action_channel)
        yield SystemCommand("Power cycle", "switch the drive off and on", self.action_power_cycle)
        yield SystemCommand(
            "Reset to the profile's defaults",
            "every drive as at start; the server keeps serving",
            self.action_reset_setup,
        )
        if not self.bench.virtual:
            yield SystemCommand(
                "Pause or resume the clock", "the model stands still; the wire answers", self.action_pause
            )
        yield SystemCommand("Restore defaults", "200FH = 1 (only while stopped)", self.action_restore_defaults)
        yield SystemCommand("Save frame log", "write the frames shown to a file", self.action_save_log)
        for tab in tabs():
            yield SystemCommand(
                f"View: {tab.title} ({tab.key.upper()})", tab.help.split(":")[0], lambda t=tab.id: self.action_tab(t)
            )
        for switch in self.bench.device_switches:
            yield SystemCommand(f"Device fault: {switch.label}", switch.how, lambda k=switch.key: self._device_fault(k))
        for key, (code, name) in self.bench.forced.items():
            yield SystemCommand(
                f"Device fault: {name} (0x{code:02X})", "latch the fault code", lambda k=key: self._device_fault(k)
            )
        for switch in LINK_SWITCHES:
            yield SystemCommand(f"Link fault: {switch.label}", switch.how, lambda k=switch.key: self._link_fault(k))
        if self.bench.virtual:
            yield SystemCommand("Time +10 s", "advance the virtual clock", lambda: self.action_advance(10))

    def _device_fault(self, key: str) -> None:
        self.get_screen_main().query_one(DeviceFaultsPanel).toggle(key)

    def _link_fault(self, key: str) -> None:
        self.get_screen_main().query_one(LinkFaultsPanel).toggle(key)
