// autoscale.test.mjs - the viewer's automatic render scale (web/autoscale.js), a pure rule run
// here in Node second by second: it lowers the scale when drawing is slow, brings it back when
// there is room again, and does not swing at the edge.

import { describe, it } from 'node:test';
import assert from 'node:assert/strict';
import { autoScaleState, nextScale, MIN_PICTURE_RATE } from '../../web/autoscale.js';

// run a list of seconds [rate, demanded] from a scale; the scale after each second
function run(seconds, scale = 1, st = autoScaleState()) {
  const out = [];
  for (const [rate, demanded] of seconds) {
    scale = nextScale(st, rate, demanded, scale);
    out.push(scale);
  }
  return out;
}
const repeat = (n, s) => Array.from({ length: n }, () => s);

describe('automatic render scale', () => {
  it('two slow demanded seconds lower one step, down to the smallest scale and no further', () => {
    const slow = [8, true];
    assert.deepEqual(run(repeat(6, slow)), [1, 0.5, 0.5, 0.35, 0.35, 0.35]);
  });

  it('one slow second, or slow seconds without frames waiting, change nothing', () => {
    assert.deepEqual(run([[8, true], [30, true], [8, true], [30, true]]), [1, 1, 1, 1]);
    assert.deepEqual(run(repeat(5, [8, false])), [1, 1, 1, 1, 1]);
  });

  it('comes back to full resolution when the drawing has room again', () => {
    const st = autoScaleState();
    let s = run(repeat(2, [8, true]), 1, st).pop();
    assert.equal(s, 0.5);
    // drawing keeps up with every frame: three good seconds raise it
    assert.deepEqual(run(repeat(3, [50, false]), s, st), [0.5, 0.5, 1]);
    // pictures that keep up with frames at 25 per second or more are good too
    const st2 = autoScaleState();
    s = run(repeat(2, [8, true]), 1, st2).pop();
    assert.deepEqual(run(repeat(3, [MIN_PICTURE_RATE * 1.25, true]), s, st2), [0.5, 0.5, 1]);
    // a demanded rate above the minimum but without the margin neither lowers nor raises
    const st3 = autoScaleState();
    s = run(repeat(2, [8, true]), 1, st3).pop();
    assert.deepEqual(run(repeat(30, [MIN_PICTURE_RATE * 1.2, true]), s, st3), repeat(30, 0.5));
  });

  it('a raise that is too slow is undone, and the next raise waits twice as long', () => {
    const st = autoScaleState();
    const lowered = run(repeat(2, [8, true]), 1, st).pop();
    assert.equal(lowered, 0.5);
    assert.deepEqual(run(repeat(3, [40, false]), lowered, st), [0.5, 0.5, 1]);
    assert.deepEqual(run(repeat(2, [9, true]), 1, st), [1, 0.5]);
    // now six good seconds are needed, not three
    assert.deepEqual(run(repeat(6, [40, false]), 0.5, st), [0.5, 0.5, 0.5, 0.5, 0.5, 1]);
  });

  it('a scale that is not in the list still lowers to the next smaller one', () => {
    assert.deepEqual(run(repeat(2, [5, true]), 0.75), [0.75, 0.5]);
  });
});
