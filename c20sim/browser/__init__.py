"""The drive in a browser tab: the real package in Pyodide, a page over the route table's operations.

- :mod:`.page`: what the page runs in Pyodide: one simulator, its line, its live audit, the terminal's master
  and the Web Serial port's endpoint (the same :class:`~c20sim.transport.endpoint.RtuEndpoint` and
  :class:`~c20sim.transport.line.Line` as ``c20sim serve``); every operation is a row of
  :data:`~c20sim.control.routes.TABLE`, called in-process. It imports nothing of the browser: bytes and
  answers cross to JavaScript as hex and JSON text, so it runs, and is tested, in CPython too.
- :mod:`.site`: ``c20sim site build DIR``: the static site (the page, Pyodide from its npm package, and the
  modules the page imports, zipped).
- ``static/``: the page itself (HTML, CSS, JavaScript).
"""
