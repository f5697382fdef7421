// autoscale.js - the viewer's automatic render scale as a pure rule, one decision a second
// (hud.js applies it; tests/web/autoscale.test.mjs runs it in Node).
//
// A second in which frames waited for a picture most of the time is "demanded": its picture
// rate is what the drawing can do. Two slow demanded seconds (below `min` pictures/s) lower
// the scale one step. While lowered, a second is good when the drawing kept up with the frames
// (not demanded) or drew at least `margin` x `min` pictures; `raiseAfter` good seconds in a row
// raise the scale one step, as a trial: pictures arrive no faster than frames, so how a larger
// scale does is only known by drawing at it. A raise followed by a drop doubles the good
// seconds the next raise needs, so a machine at the edge tries less and less often.

export const MIN_PICTURE_RATE = 20;
export const AUTO_SCALES = [1, 0.5, 0.35];
const RAISE_MARGIN = 1.25;
const RAISE_AFTER_S = 3;

/** the rule's state before the first second */
export function autoScaleState() {
  return { slow: 0, good: 0, raiseAfter: RAISE_AFTER_S, raisedLast: false };
}

/**
 * One second's decision. rate: pictures drawn per second; demanded: frames waited for a
 * picture most of the second; scale: the current scale (one of AUTO_SCALES). Returns the new
 * scale (the same when nothing changes) and updates st.
 */
export function nextScale(st, rate, demanded, scale, min = MIN_PICTURE_RATE) {
  if (!(rate >= 0)) return scale;
  // the next smaller and the next larger scale of the list (the list is in falling order)
  const down = AUTO_SCALES.find((s) => s < scale - 1e-6);
  const up = AUTO_SCALES.filter((s) => s > scale + 1e-6).pop();
  if (demanded && rate < min) {
    st.good = 0;
    st.slow++;
    if (st.slow < 2 || down === undefined) return scale;
    st.slow = 0;
    if (st.raisedLast) st.raiseAfter *= 2;
    st.raisedLast = false;
    return down;
  }
  st.slow = 0;
  if (up === undefined) {
    st.good = 0;
    return scale;
  }
  // how a larger scale would do is only known by trying it: a raise that turns out too slow
  // is undone, and the next one waits longer
  st.good = !demanded || rate >= RAISE_MARGIN * min ? st.good + 1 : 0;
  if (st.good < st.raiseAfter) return scale;
  st.good = 0;
  st.raisedLast = true;
  return up;
}
