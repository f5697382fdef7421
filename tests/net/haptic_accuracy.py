"""The haptic model's accuracy between frames (docs/protocol.md, "The model between frames").

    /usr/bin/python3 tests/net/haptic_accuracy.py          (needs build/squish; run by make bench)

A slow press (the scene's own probe, 3 cm/s for cube-poke and the organ) is run twice on a
--lockstep server: at the scene's 50 Hz with the haptic channel open, and as a reference at
500 Hz (the same scene with frame_rate 500: the pose is applied every 2 ms, at about every
substep of the 50 Hz run). At each 50 Hz frame the model (stiffness 0: the tool is the device)
is asked for the force at the mid-frame pose, 10 ms ahead; the reference's feedback at that
time is the truth. Also reported: the zero-order hold (the last frame's force, what a client
without the model gets), and the floor: the 50 Hz run's own frame force against the reference
at the frame's end (how far the two runs differ before any model is used). Then the reference
the issue names: the same 50 Hz scene stepped with the pose applied at every substep (the
channel's lockstep "ramp"), whose frame force (the mean over the frame's substeps) stands for
the force at mid-frame, against the model made after the frame before (run_ramp). Prints the
median and 90th percentile relative error of the force along the press, over the frames in
contact with more than 1 N.
"""
import json
import os
import sys
import tempfile
import time

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
sys.path.insert(0, os.path.join(ROOT, "web"))
from squish_client import SquishClient  # noqa: E402
from pyserver import load_scene, lockstep_server  # noqa: E402

SQUISH = os.environ.get("SQUISH", os.path.join(ROOT, "build", "squish"))

# name: (scene file, press start, press direction (unit), speed m/s, press time s, tool radius,
# lod override or None, the channel's focus or None for its default). The scenes as shipped are
# adaptive, and the channel keeps the finest level about its tool (its focus); with focus 0 (the
# lod's criterion alone) a split or merge near the tool changes the force in a step no model of
# one frame foresees; the fixed-lod twins (the finest level everywhere) show the model's own
# error.
FIXED = {"mode": "fixed", "level": 2, "max_level": 2}
CASES = {
    "cube-poke": ("cube-poke.json", (0.5, 0.5, 1.10), (0, 0, -1), 0.03, 1.5, 0.12, None, None),
    "organ": ("organ.json", (0.1, 0.1, 0.16), (0, 0, -1), 0.03, 1.5, 0.03, None, None),
    "cube-poke-criterion": ("cube-poke.json", (0.5, 0.5, 1.10), (0, 0, -1), 0.03, 1.5, 0.12, None, 0),
    "organ-criterion": ("organ.json", (0.1, 0.1, 0.16), (0, 0, -1), 0.03, 1.5, 0.03, None, 0),
    "cube-poke-fixed": ("cube-poke.json", (0.5, 0.5, 1.10), (0, 0, -1), 0.03, 1.5, 0.12, FIXED, None),
    "organ-fixed": ("organ.json", (0.1, 0.1, 0.16), (0, 0, -1), 0.03, 1.5, 0.03, FIXED, None),
}


def scenes(tmp):
    for name, (f, *_r, lod, _focus) in CASES.items():
        s = load_scene(os.path.join(ROOT, "meshes", "scenes", f))
        for b in s["bodies"]:
            if lod:
                b["lod"] = dict(lod)
        s["tools"] = []  # the press is driven by this script
        for rate, suffix in ((50, ""), (500, "-ref")):
            s["name"] = name + suffix
            s["frame_rate"] = rate
            json.dump(s, open(os.path.join(tmp, name + suffix + ".json"), "w"))


def pose(start, d, v, t):
    return [start[i] + d[i] * v * t for i in range(3)]


def run(url, name):
    _f, start, d, v, T, radius, _lod, focus = CASES[name]
    nframes = int(T * 50)
    # reference: 500 Hz, the pose every 2 ms; feedback of every frame, by time (a channel that
    # sends no pose, open for its focus only)
    ref = {}
    with SquishClient.connect(url) as c:
        c.open(name + "-ref")
        c.tool(id=2, shape="sphere", pos=pose(start, d, v, 0), radius=radius)
        c.haptic_open(2, focus=focus)
        for k in range(1, nframes * 10 + 1):
            c.tool(id=2, pos=pose(start, d, v, k * 0.002))
            c.step(1)
            f = c.frames[0].tools[0]["force"]
            ref[k] = sum(f[i] * -d[i] for i in range(3))  # the reaction along the press
    # the model: 50 Hz, the channel answers at mid-frame
    model, hold = {}, {}
    with SquishClient.connect(url) as c:
        c.open(name)
        c.tool(id=2, shape="sphere", pos=pose(start, d, v, 0), radius=radius)
        ch = c.haptic_open(2, stiffness=0, damping=0, focus=focus)["channel"]
        for k in range(1, nframes + 1):
            # the frame ending at 20 k ms is stepped with the pose of its end (as the reference)
            c.haptic(ch, pose(start, d, v, k * 0.02), k * 0.02)
            c.step(1)
            time.sleep(0.002)  # under the channel's rate limit
            c.haptic(ch, pose(start, d, v, k * 0.02), k * 0.02 + 0.0005)  # the new model, blend start
            f = c.haptic(ch, pose(start, d, v, k * 0.02 + 0.01), k * 0.02 + 0.011)  # blended in
            model[k] = sum(f["force"][i] * -d[i] for i in range(3))
            hold[k] = sum(c.frames[0].tools[0]["force"][i] * -d[i] for i in range(3))
    errs_m, errs_h, errs_f = [], [], []
    for k in range(1, nframes + 1):
        at_frame = ref.get(10 * k)
        if at_frame is not None and abs(at_frame) >= 1.0:
            errs_f.append(abs(hold[k] - at_frame) / abs(at_frame))
        truth = ref.get(10 * k + 5)  # 500 Hz frame 10 k + 5 ends at 20 k + 10 ms
        if truth is None or abs(truth) < 1.0:
            continue
        errs_m.append(abs(model[k] - truth) / abs(truth))
        errs_h.append(abs(hold[k] - truth) / abs(truth))
    return errs_m, errs_h, errs_f


def run_ramp(url, name):
    """The run the issue names: the same 50 Hz scene stepped with the pose applied at every
    substep (the channel's lockstep ramp, from each frame's start pose to its end pose). Its
    frame force, the mean over the frame's substeps, stands for the force at mid-frame; the
    model made after frame k is asked at frame k+1's mid-frame pose."""
    _f, start, d, v, T, radius, _lod, focus = CASES[name]
    nframes = int(T * 50)
    truth, model = {}, {}
    with SquishClient.connect(url) as c:
        c.open(name)
        c.tool(id=2, shape="sphere", pos=pose(start, d, v, 0), radius=radius)
        ch = c.haptic_open(2, stiffness=0, damping=0, ramp=True, focus=focus)["channel"]
        c.haptic(ch, pose(start, d, v, 0), 0.0)
        c.step(1)  # the ramp's first end pose
        for k in range(1, nframes + 1):
            c.haptic(ch, pose(start, d, v, k * 0.02), k * 0.02 - 0.001)  # frame k ramps to it
            c.step(1)
            truth[k] = sum(c.frames[0].tools[0]["force"][i] * -d[i] for i in range(3))
            time.sleep(0.002)
            c.haptic(ch, pose(start, d, v, k * 0.02), k * 0.02 + 0.0005)  # the new model, blend start
            f = c.haptic(ch, pose(start, d, v, k * 0.02 + 0.01), k * 0.02 + 0.011)  # blended in
            model[k + 1] = sum(f["force"][i] * -d[i] for i in range(3))
    errs_m, errs_h = [], []
    for k in range(2, nframes + 1):
        if abs(truth[k]) < 1.0:
            continue
        errs_m.append(abs(model[k] - truth[k]) / abs(truth[k]))
        errs_h.append(abs(truth[k - 1] - truth[k]) / abs(truth[k]))
    return errs_m, errs_h


def q(a, p):
    s = sorted(a)
    return s[min(len(s) - 1, int(p * len(s)))] if s else float("nan")


def main():
    tmp = tempfile.mkdtemp(prefix="squish-haptic-acc-")
    scenes(tmp)
    with lockstep_server(SQUISH, tmp, ("--rate", "100000")) as url:
        for name in CASES:
            em, eh, ef = run(url, name)
            print(f"{name}: slow press 3 cm/s, force at mid-frame against the 500 Hz reference, "
                  f"{len(em)} frames over 1 N: model median {100 * q(em, 0.5):.1f} % p90 {100 * q(em, 0.9):.1f} %; "
                  f"zero-order hold median {100 * q(eh, 0.5):.1f} % p90 {100 * q(eh, 0.9):.1f} %; "
                  f"floor (the 50 Hz frame's own force at its end against the reference) median "
                  f"{100 * q(ef, 0.5):.1f} % p90 {100 * q(ef, 0.9):.1f} % (aim: model within 5 %)")
            em, eh = run_ramp(url, name)
            print(f"{name}: slow press 3 cm/s, force at mid-frame against the 50 Hz run stepped with the pose "
                  f"at every substep (lockstep ramp; its frame force for the mid-frame force), {len(em)} frames "
                  f"over 1 N: model median {100 * q(em, 0.5):.1f} % p90 {100 * q(em, 0.9):.1f} %; zero-order hold "
                  f"median {100 * q(eh, 0.5):.1f} % p90 {100 * q(eh, 0.9):.1f} % (aim: model within 5 %)")


if __name__ == "__main__":
    main()
