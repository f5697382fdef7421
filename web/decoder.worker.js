// decoder.worker.js - inflates and decodes binary messages off the main thread, so drawing
// and input never delay frames (and frames never delay input). Messages: {id, buf} in,
// {id, msg} or {id, error} out; typed arrays are transferred, not copied.

import { decodeBinary } from './codec.js';

self.onmessage = async (ev) => {
  const { id, buf } = ev.data;
  try {
    const msg = await decodeBinary(buf);
    const buffers = new Set();
    for (const k of ['rest', 'tris', 'disp', 'levels', 'pos']) if (msg[k]) buffers.add(msg[k].buffer);
    self.postMessage({ id, msg }, [...buffers]);
  } catch (e) {
    self.postMessage({ id, error: e.message });
  }
};
