// The calibration core as WebAssembly: mag-cal-core with magcal's parser
// and reports (crate mag-cal-web). Every call returns the JSON document the
// core wrote; this file only moves bytes in and out of its memory.
//
// A trap (a bug in the core: it is built to return errors, not to panic)
// leaves that instance unusable, so the core is started again from the
// compiled module and the call throws a `CoreRestarted` error: the caller
// has lost the live collection and says so.

export class CoreRestarted extends Error {}

export async function loadCore(url) {
  const imports = { env: { now_us: () => performance.now() * 1000 } };
  const module = await WebAssembly.compileStreaming(fetch(url));
  let x = (await WebAssembly.instantiate(module, imports)).exports;
  const encoder = new TextEncoder();
  const decoder = new TextDecoder();

  // Runs f(ptr, len, ...) with each byte array copied into the core's
  // memory, then frees them; restarts the core after a trap.
  function call(arrays, f) {
    const blocks = [];
    try {
      for (const bytes of arrays) {
        const ptr = x.mc_alloc(bytes.length);
        blocks.push([ptr, bytes.length]);
        new Uint8Array(x.memory.buffer, ptr, bytes.length).set(bytes);
      }
      const result = f(x, ...blocks.flat());
      for (const [ptr, len] of blocks) x.mc_free(ptr, len);
      return result;
    } catch (err) {
      if (!(err instanceof WebAssembly.RuntimeError)) throw err;
      x = new WebAssembly.Instance(module, imports).exports;
      throw new CoreRestarted(`the core stopped (${err.message}) and was restarted`);
    }
  }

  function output() {
    const bytes = new Uint8Array(x.memory.buffer, x.mc_out_ptr(), x.mc_out_len());
    return JSON.parse(decoder.decode(bytes));
  }

  const opts = (options) => encoder.encode(JSON.stringify(options));

  return {
    // The core's method names (default first) and coverage grid.
    info() {
      call([], (e) => e.mc_info());
      return output();
    },
    // Parses and fits a file's bytes, as `magcal fit` does.
    fit(bytes, options) {
      call([bytes, opts(options)], (e, ...args) => e.mc_fit(...args));
      return output();
    },
    // Empties the live collection.
    liveReset() {
      call([], (e) => e.mc_live_reset());
    },
    // One line of the serial stream into the core's collector.
    liveLine(line) {
      call([encoder.encode(line)], (e, ...args) => e.mc_live_line(...args));
      return output();
    },
    // Fits the collected samples.
    liveFit(options) {
      call([opts(options)], (e, ...args) => e.mc_live_fit(...args));
      return output();
    },
  };
}
