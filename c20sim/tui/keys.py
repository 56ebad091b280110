"""Keys in turn: each key read from the terminal is passed on once the key before it has been handled.

Textual passes every key it reads to the widget focused at that moment, at once, and a key that is not the
widget's own (Enter, Home, ctrl+k, F3, ``/``: its bindings) is resolved only when it has bubbled back up to the
app, through each parent's queue. Keys read together (a paste, ``tmux send-keys F6 / speed Enter``, a fast
typist on a loaded machine) therefore went to the widget the key before them was about to leave, and a field's
letters overtook its own Home and ctrl+k: ``F3 Home ctrl+k 36 Enter`` applied an empty field, ``F6 / speed
Enter`` stopped the drive (``s``) and found nothing.

:class:`KeysInTurn` holds a key read while the one before it is still on its way, and passes it on once that
one has been handled: stopped by a widget (a letter typed into a field), taken by a binding on its way up, or
done at the app. Each key then meets the focus the keys before it left, as it would typed slowly. A key is
never held longer than :data:`KEY_TURN_S` (a key handled somewhere this cannot see: the next one goes on), and
at most :data:`KEY_BACKLOG` keys are held (more are dropped, and said once).
"""

from __future__ import annotations

import asyncio
from collections import deque

from textual import events
from textual.app import App

__all__ = ["KEY_BACKLOG", "KEY_TURN_S", "KeysInTurn"]

#: The longest a key waits for the one before it (assumed: longer than any handler of a key takes on a loaded
#: machine, short enough not to be felt when a key's end cannot be seen).
KEY_TURN_S = 0.5
#: The most keys held at once (assumed: a long paste); beyond it a key is dropped.
KEY_BACKLOG = 512
#: How often the key on its way is looked at (its flag of being stopped set by the widget that took it).
_LOOK_S = 0.002


class KeysInTurn(App[int]):
    """An app that hands its keys on one at a time (the module's docstring says why)."""

    def __init__(self) -> None:
        super().__init__()
        self._held: deque[events.Key] = deque()
        self._on_way: events.Key | None = None
        self._released: set[int] = set()
        self._watch: asyncio.Task[None] | None = None
        #: keys dropped beyond KEY_BACKLOG
        self.keys_dropped = 0

    async def on_event(self, event: events.Event) -> None:
        if not isinstance(event, events.Key) or event.is_forwarded:
            await super().on_event(event)
            return
        if id(event) in self._released:
            self._released.discard(id(event))
        elif self._on_way is not None or self._held:
            self._hold(event)
            return
        self._on_way = event
        await super().on_event(event)  # a priority binding, or passed on to the focused widget
        if not event.is_forwarded:
            self._next()  # taken by a priority binding (a tab's key): done
        elif self._on_way is event:
            self._watch = asyncio.create_task(self._until_handled(event))

    async def _on_key(self, event: events.Key) -> None:
        # Back at the app. Textual calls each class's _on_key (this one before App's, which runs its bindings), so
        # the next key goes on once this message is done with, bindings and all.
        if event is self._on_way:
            self.call_next(self._done, event)

    def _done(self, event: events.Key) -> None:
        if event is self._on_way:
            self._next()

    def _hold(self, event: events.Key) -> None:
        if len(self._held) >= KEY_BACKLOG:
            self.keys_dropped += 1
            if self.keys_dropped == 1:
                self.notify(f"keys come faster than they are handled: dropped beyond {KEY_BACKLOG}", severity="warning")
            return
        self._held.append(event)

    async def _until_handled(self, event: events.Key) -> None:
        """Stopped by a widget (typed into a field), or not seen back in time: the next key goes on."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + KEY_TURN_S
        while self._on_way is event and not event._stop_propagation and loop.time() < deadline:
            await asyncio.sleep(_LOOK_S)
        if self._on_way is event:
            self._next()

    def stop_keys(self) -> None:
        """The app closing: no key is waited for any more."""
        if self._watch is not None:
            self._watch.cancel()
        self._held.clear()
        self._on_way = None

    def _next(self) -> None:
        self._on_way = None
        if self._held:
            event = self._held.popleft()
            self._released.add(id(event))
            self.post_message(event)
