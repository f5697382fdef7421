// client.mjs - the tests' name for the client library web/squish-client.js (one client for
// the tests, the benchmarks, user scripts and, through web/codec.js, the viewer).
// decodeHeader/decodeBinary keep the synchronous forms the tests were written against.
import { decodeMessage, parseHeader } from '../../web/squish-client.js';

export * from '../../web/squish-client.js';

/** Decode the 64-byte header of a binary message (Buffer, Uint8Array or ArrayBuffer). */
export function decodeHeader(buf) {
  const h = parseHeader(buf);
  h.zbytes = h.zBytes;
  return h;
}

/** Decode a whole binary message (synchronously, in Node); `rest` gives frames positions. */
export function decodeBinary(buf, rest) {
  return decodeMessage(buf, rest);
}
