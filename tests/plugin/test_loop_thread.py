"""The plugin's background loop: stopping it never tries to close a loop that is still running."""

from __future__ import annotations

import threading

import pytest

from c20sim.testing import _LoopThread


def test_a_loop_that_does_not_stop_is_reported_not_closed() -> None:
    thread = _LoopThread()
    release = threading.Event()
    started = threading.Event()

    def block() -> None:
        started.set()
        release.wait(10)

    thread.loop.call_soon_threadsafe(block)
    assert started.wait(5)
    with pytest.raises(RuntimeError, match=r"^c20sim: the simulator's event loop did not stop within 0\.1 s"):
        thread.stop(timeout=0.1)
    assert not thread.loop.is_closed()
    release.set()
    thread.stop()
    assert thread.loop.is_closed()
    thread.stop()  # a second stop does nothing
