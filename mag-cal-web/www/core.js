// The calibration core as WebAssembly: mag-cal-core with magcal's parser
// and reports (crate mag-cal-web). Every call returns the JSON document the
// core wrote; this file only moves bytes in and out of its memory.

export async function loadCore(url) {
  const imports = { env: { now_us: () => performance.now() * 1000 } };
  const { instance } = await WebAssembly.instantiateStreaming(fetch(url), imports);
  const x = instance.exports;
  const encoder = new TextEncoder();
  const decoder = new TextDecoder();

  // Calls f(ptr, len, ...) with each byte array copied into the core's
  // memory, then frees them.
  function withBytes(arrays, f) {
    const blocks = arrays.map((bytes) => {
      const ptr = x.mc_alloc(bytes.length);
      new Uint8Array(x.memory.buffer, ptr, bytes.length).set(bytes);
      return [ptr, bytes.length];
    });
    try {
      return f(...blocks.flat());
    } finally {
      for (const [ptr, len] of blocks) x.mc_free(ptr, len);
    }
  }

  function output() {
    const bytes = new Uint8Array(x.memory.buffer, x.mc_out_ptr(), x.mc_out_len());
    return JSON.parse(decoder.decode(bytes));
  }

  const opts = (options) => encoder.encode(JSON.stringify(options));

  return {
    // Parses and fits a file's bytes, as `magcal fit` does.
    fit(bytes, options) {
      withBytes([bytes, opts(options)], x.mc_fit);
      return output();
    },
    // Empties the live collection.
    liveReset() {
      x.mc_live_reset();
    },
    // One line of the serial stream into the core's collector.
    liveLine(line) {
      withBytes([encoder.encode(line)], x.mc_live_line);
      return output();
    },
    // Fits the collected samples.
    liveFit(options) {
      withBytes([opts(options)], x.mc_live_fit);
      return output();
    },
  };
}
