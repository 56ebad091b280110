// The Web Serial transport: a port of Web Serial's shape (open, readable, writable, close) served by the page's
// Python (c20sim.browser.page.SerialServe: the RtuEndpoint and Line of `c20sim serve --serial`).
//
// Bytes read go to Python as hex the moment the browser hands them over; Python frames them and answers on the
// line, and hands each reply back as hex to put on the port. While a request is on the line, Python asks the
// reading to pause (the bytes wait in the port's buffer), as serve stops reading the serial port. A 2009H baud
// change is followed after the acknowledging reply has been written: Web Serial cannot change the speed of an
// open port, so the port is closed and opened again at the new baud.

/** Line formats the page offers, as Web Serial names their parts. */
export const FORMATS = {
  "8N1": { dataBits: 8, parity: "none", stopBits: 1 },
  "8E1": { dataBits: 8, parity: "even", stopBits: 1 },
  "8O1": { dataBits: 8, parity: "odd", stopBits: 1 },
  "8N2": { dataBits: 8, parity: "none", stopBits: 2 },
};

/** Replies waiting to be written at most: a master waits for each, so more means the port is stuck. */
export const MAX_QUEUED = 16;

export function toHex(bytes) {
  let out = "";
  for (const b of bytes) out += b.toString(16).padStart(2, "0");
  return out;
}

export function fromHex(hex) {
  const out = new Uint8Array(hex.length / 2);
  for (let i = 0; i < out.length; i++) out[i] = parseInt(hex.substr(2 * i, 2), 16);
  return out;
}

/**
 * Serve `port` for the page `page` (a c20sim.browser.page.Page, a Pyodide proxy) at the line's baud and `format`.
 * Returns {done, close(), stats}; `log(text)` is told what happens (opened, baud changes, errors).
 */
export async function serveOn(port, page, { format = "8N1", log = () => {} } = {}) {
  const shape = FORMATS[format];
  if (!shape) throw new Error(`serial format ${format}: choose one of ${Object.keys(FORMATS).join(", ")}`);
  let baud = JSON.parse(page.state()).baud;
  const options = (rate) => ({ baudRate: rate, ...shape, bufferSize: 4096, flowControl: "none" });
  await port.open(options(baud));
  log(`opened at ${baud} baud ${format}`);

  const stats = { baud, format, chunks: 0, bytesIn: 0, replies: 0, bytesOut: 0, dropped: 0, reopened: 0 };
  let writing = Promise.resolve();
  let queued = 0;
  let reader = null;
  let closed = false;
  let pendingBaud = null;
  let paused = false;
  let wake = null;

  const write = (hex) => {
    if (queued >= MAX_QUEUED) {
      stats.dropped += 1;
      log(`reply dropped: ${MAX_QUEUED} replies wait for the port already`);
      return;
    }
    queued += 1;
    const bytes = fromHex(hex);
    writing = writing
      .then(async () => {
        const writer = port.writable.getWriter();
        try {
          await writer.write(bytes);
          stats.replies += 1;
          stats.bytesOut += bytes.length;
        } finally {
          writer.releaseLock();
        }
      })
      .catch((err) => log(`write failed: ${err.message || err}`))
      .finally(() => { queued -= 1; });
  };
  const reopen = (rate) => {
    pendingBaud = rate;
    // after the acknowledging reply has gone at the old baud: end the read, and the loop reopens the port
    writing.then(() => reader && reader.cancel().catch(() => {}));
  };
  const pause = () => { paused = true; };
  const resume = () => {
    paused = false;
    if (wake) { const w = wake; wake = null; w(); }
  };
  const serve = await page.open_serial(write, reopen, pause, resume, format);

  const run = async () => {
    try {
      while (!closed) {
        reader = port.readable.getReader();
        try {
          for (;;) {
            if (paused) await new Promise((resolve) => { wake = resolve; });
            if (closed || pendingBaud !== null) break;
            const { value, done } = await reader.read();
            if (done) break;
            if (value && value.length) {
              stats.chunks += 1;
              stats.bytesIn += value.length;
              serve.feed(toHex(value));
            }
          }
        } finally {
          reader.releaseLock();
          reader = null;
        }
        if (closed) break;
        if (pendingBaud === null) { log("the port closed"); break; }
        await writing;
        await port.close();
        baud = pendingBaud;
        pendingBaud = null;
        await port.open(options(baud));
        stats.baud = baud;
        stats.reopened += 1;
        log(`reopened at ${baud} baud ${format} (2009H)`);
      }
    } catch (err) {
      log(`serial port: ${err.message || err}`);
    } finally {
      serve.close();
      closed = true;
    }
  };
  const done = run();

  return {
    done,
    stats,
    async close() {
      closed = true;
      resume();
      if (reader) await reader.cancel().catch(() => {});
      await done;
      await writing;
      await port.close().catch(() => {});
      log("closed");
    },
  };
}
