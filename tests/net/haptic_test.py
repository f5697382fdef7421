"""Haptic channel tests against a real `squish serve` (docs/protocol.md, "Haptic channel").

  haptic_test.py device URL   (a --lockstep server) a simulated device: a 0.2 kg mass held by a
                              hand spring, stepped at 1 kHz by this client, presses the
                              cube-poke top, drags, releases; checks passivity, buzz, no reset,
                              the same numbers twice (lockstep determinism)
  haptic_test.py scene RATE DIR   writes DIR/cube-poke.json: cube-poke at RATE frames a second,
                              and DIR/cube-poke-coupled.json: cube-poke with a "haptic" block
  haptic_test.py scene-haptic URL   (a server of that directory) a channel takes the scene's
                              haptic defaults, a request's values win
  haptic_test.py device-rate URL RATE   (a --lockstep server of that scene) the same device at
                              the default coupling: passive, no reset (a frame rate other than
                              the shipped 50 Hz)
  haptic_test.py focus URL    (a --lockstep server) a channel's focus keeps cube-poke's finest
                              level about its tool; focus 0 or a closed channel does not
  haptic_test.py input URL    (a realtime server) answers; NaN, out of bounds, not owner, bad
                              message; a 20 kHz flood while a viewer's frame rate is checked

Prints "ok - ..." / "not ok - ..." lines and "haptic-X: N passed, N failed"; exits 1 on a failure.
"""
import asyncio
import cmath
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "web"))
from squish_client import SquishClient, SquishError, encode_pose  # noqa: E402
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pyserver import load_scene  # noqa: E402

passed = failed = 0


def check(cond, what):
    global passed, failed
    if cond:
        passed += 1
        print(f"ok - {what}")
    else:
        failed += 1
        print(f"not ok - {what}")
    return cond


# ---------------------------------------------------------------- the simulated device
DT = 0.001          # device period, s (1 kHz)
MASS = 0.2          # kg
HAND_K = 300.0      # N/m, the hand's spring on the device
HAND_B = 5.0        # N s/m, the hand's damping (relative to the hand's own motion)
FRAME = 0.02        # the scene's frame period (50 Hz): 20 device steps per frame


def hand_target(t):
    """press from 10 cm above the top (z = 1) to 4 cm into it over 1 s, hold 0.2 s, drag 8 cm
    in x over 0.5 s, lift clear over 0.5 s, rest 0.3 s"""
    x0, z_top, z_in = 0.5, 1.22, 1.07
    if t < 1.0:
        return (x0, 0.5, z_top + (z_in - z_top) * t)
    if t < 1.2:
        return (x0, 0.5, z_in)
    if t < 1.7:
        return (x0 + 0.08 * (t - 1.2) / 0.5, 0.5, z_in)
    if t < 2.2:
        return (x0 + 0.08, 0.5, z_in + (1.25 - z_in) * (t - 1.7) / 0.5)
    return (x0 + 0.08, 0.5, 1.25)


def scene_at_rate(directory, rate):
    """cube-poke.json in directory: the shipped scene at `rate` frames a second"""
    s = load_scene(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "meshes", "scenes",
                                "cube-poke.json"))
    s["frame_rate"] = rate
    os.makedirs(directory, exist_ok=True)
    json.dump(s, open(os.path.join(directory, "cube-poke.json"), "w"))


COUPLED = {"stiffness": 700, "damping": 3, "device_mass": 0.3, "focus": 2}


def scene_coupled(directory):
    """cube-poke-coupled.json in directory: the shipped cube-poke with a "haptic" block"""
    s = load_scene(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "meshes", "scenes",
                                "cube-poke.json"))
    s["name"] = "cube-poke-coupled"
    s["haptic"] = dict(COUPLED)
    os.makedirs(directory, exist_ok=True)
    json.dump(s, open(os.path.join(directory, "cube-poke-coupled.json"), "w"))


def test_scene_haptic(url):
    """a scene's "haptic" block gives the defaults of a channel opened on it; a request's own
    values win; a scene without one leaves the channel's defaults"""
    with SquishClient.connect(url, client="haptic-scene") as c:
        c.open("cube-poke-coupled")
        c.tool(id=2, shape="sphere", pos=[0.5, 0.5, 1.3], radius=0.12)
        r = c.haptic_open(2)
        got = {k: r[k] for k in COUPLED}
        check(got == COUPLED, f"a channel takes the scene's haptic defaults ({got})")
        check(r["stiffness_safe"] == 750, f"stiffness_safe for the scene's 0.3 kg at 50 Hz: {r['stiffness_safe']} N/m")
        r = c.haptic_open(2, focus=1, damping=2)
        check(r["focus"] == 1 and r["damping"] == 2 and r["stiffness"] == 700,
              f"a request's values win over the scene's ({r['focus']}, {r['damping']}, {r['stiffness']})")
    with SquishClient.connect(url, client="haptic-scene") as c:
        c.open("cube-poke")
        c.tool(id=2, shape="sphere", pos=[0.5, 0.5, 1.3], radius=0.12)
        r = c.haptic_open(2)
        check(r["focus"] == 3 and r["device_mass"] == 0.2 and r["damping"] == 2 and
              r["stiffness"] == r["stiffness_safe"],
              f"a scene without one: the channel's defaults (focus {r['focus']}, {r['device_mass']} kg, "
              f"{r['damping']} N s/m, {r['stiffness']} N/m)")


def tolerance(work):
    """the passivity check's tolerance: 5 % of the most energy the channel absorbed (measured
    2.6 % at the default coupling: the passivity controller acts one device step after the
    first contact's push, docs/protocol.md "Haptic channel")"""
    return 0.05 * max(1e-3, -min(work))


def run_device(url, stiffness, damping, mass=MASS, device_mass=None, frame=FRAME):
    """one run of a device of `mass` kg (device_mass: the mass the channel is told, None: not
    told) on a scene of frame period `frame` s; returns (forces [(fx, fy, fz)], port work W(t)
    list, resets, stats)"""
    with SquishClient.connect(url, client="haptic-device") as c:
        c.open("cube-poke")
        c.tool(id=1, shape="sphere", pos=[0.5, 0.5, 1.3], active=False)   # the scene's finger off
        c.tool(id=2, shape="sphere", pos=[0.5, 0.5, 1.22], radius=0.12)
        ch = c.haptic_open(2, stiffness=stiffness, damping=damping, device_mass=device_mass)["channel"]
        resets = []
        c.on("event", lambda e: resets.append(e) if e.get("kind") == "reset" else None)
        c.step(1)
        x = list(hand_target(0.0))
        v = [0.0, 0.0, 0.0]
        forces, work, w = [], [], 0.0
        n = int(2.5 / DT)
        due = time.time()
        for k in range(n):
            t = k * DT
            # the channel's rate limit holds in lockstep too (2000 poses/s): at most 1500 poses
            # per second, never catching up in a burst after a slow step
            ahead = due - time.time()
            if ahead > 0:
                time.sleep(ahead)
            due = max(due, time.time()) + 1 / 1500.0
            f = c.haptic(ch, x, t)["force"]
            h = hand_target(t)
            hn = hand_target(t + DT)
            hv = [(hn[i] - h[i]) / DT for i in range(3)]
            # semi-implicit Euler of the device mass: hand spring + damper + the channel's force
            for i in range(3):
                a = (f[i] + HAND_K * (h[i] - x[i]) + HAND_B * (hv[i] - v[i])) / mass
                v[i] += DT * a
            xn = [x[i] + DT * v[i] for i in range(3)]
            # the work the channel did on the device over this step (force held over the step)
            w += sum(f[i] * (xn[i] - x[i]) for i in range(3))
            x = xn
            forces.append(f)
            work.append(w)
            if (k + 1) % round(frame / DT) == 0:
                c.step(1)
        st = c.stats()
        return forces, work, resets, st


def high_fraction(samples, dt, fc):
    """fraction of the signal's energy (mean removed) above fc Hz, by a plain DFT"""
    n = len(samples)
    mean = sum(samples) / n
    s = [x - mean for x in samples]
    total = sum(x * x for x in s) * n  # Parseval: sum |X_k|^2 = n sum |x|^2
    if total <= 0:
        return 0.0
    k0 = int(math.ceil(fc * n * dt))
    high = 0.0
    for k in range(k0, n // 2 + 1):
        w = -2j * math.pi * k / n
        X = sum(s[j] * cmath.exp(w * j) for j in range(0, n))
        high += abs(X) ** 2 * (1 if k == n // 2 else 2)
    return high / total


def test_device(url):
    forces, work, resets, st = run_device(url, 1000.0, 2.0)
    fz = [f[2] for f in forces]
    peak = max(fz)
    print(f"# device: peak push {peak:.2f} N, port work max {max(work):+.4f} J, min {min(work):+.4f} J, "
          f"final {work[-1]:+.4f} J")
    check(peak > 1.0, f"the press is felt: peak upward force {peak:.2f} N > 1 N")
    # passivity: the channel never gives the device more energy than it took from it
    # (W(t) = work done on the device so far <= a tolerance, at every step)
    tol = tolerance(work)
    check(max(work) <= tol, f"passive: the channel's net work on the device stays <= {tol:.2e} J "
                            f"(max {max(work):+.2e} J, absorbed up to {-min(work):.4f} J)")
    released = all(abs(f[2]) < 1e-9 for f in forces[-200:])
    check(released, "released: force 0 over the last 0.2 s, lifted clear")
    frac = high_fraction(fz[:2000], DT, 100.0)
    print(f"# device: fraction of the force's energy above 100 Hz: {frac:.4f}")
    # bound: 10 % (measured 5.1 % with the 10 ms model blend, 14 % without it)
    check(frac < 0.10, f"no buzz: {100 * frac:.2f} % of the force's energy above 100 Hz (< 10 %)")
    check(not resets and st.get("resets", 0) == 0, "no reset of the body")
    ch = st["haptic"]["channels"][0]
    check(ch["answered"] == len(forces) and ch["dropped_rate"] == 0 and ch["dropped_bad"] == 0,
          f"every pose answered ({ch['answered']} of {len(forces)}), none dropped")
    # lockstep: the same poses give the same forces
    forces2, _, _, _ = run_device(url, 1000.0, 2.0)
    check(forces2 == forces, "lockstep: a second run gives bit-identical forces")
    # a lighter device (0.1 kg) that states its mass: the passivity controller's damping stays
    # below mass / pose interval (100 N s/m here). Its fixed 200 N s/m made this device ring
    # (b dt / m = 2, the edge of a sampled damper) until its positions were not finite and its
    # poses were refused. (The loop with this device and the default coupling is not passive:
    # docs/protocol.md "Virtual coupling and passivity" gives the measured limits.)
    try:
        forces, work, resets, st = run_device(url, 1000.0, 2.0, mass=0.1, device_mass=0.1)
        ch = st["haptic"]["channels"][0]
        finite = all(math.isfinite(f[i]) for f in forces for i in range(3))
        check(finite and ch["answered"] == len(forces) == 2500 and ch["dropped_bad"] == 0 and not resets,
              f"a 0.1 kg device stating its mass: every pose answered ({ch['answered']}), none bad, no reset")
    except TimeoutError as e:
        check(False, f"a 0.1 kg device stating its mass: {e}")


def test_device_rate(url, rate):
    """the device at the default coupling on cube-poke stepped at `rate` Hz: a new frame's model
    is blended in over half the frame period. When the blend was a fixed 10 ms, at 100 Hz it
    never ended before the next model came, and this run gave the device 3.8 times the
    tolerance (measured); now 0.0"""
    forces, work, resets, st = run_device(url, 1000.0, 2.0, frame=1.0 / rate)
    tol = tolerance(work)
    check(max(fz[2] for fz in forces) > 1.0, f"{rate:g} Hz frames: the press is felt")
    check(max(work) <= tol, f"{rate:g} Hz frames: passive, the channel's net work on the device stays <= "
                            f"{tol:.2e} J (max {max(work):+.2e} J)")
    check(not resets and st.get("resets", 0) == 0, f"{rate:g} Hz frames: no reset of the body")


def test_focus(url):
    """a channel's focus keeps an adaptive body's finest level about its tool: cube-poke at rest
    with the tool clear of it refines nothing by its criterion; with a channel of focus 3 the
    nodes within 3 radii split to the finest level (cube-poke's level 2) and stay; with focus 0,
    or once the channel is closed, the criterion alone (no load) splits none and merges them"""
    def finest(c):
        return c.stats()["bodies"][0]["active_nodes"][2]

    with SquishClient.connect(url, client="haptic-focus") as c:
        c.open("cube-poke")
        c.tool(id=1, shape="sphere", pos=[0.5, 0.5, 1.3], active=False)
        c.tool(id=2, shape="sphere", pos=[0.5, 0.5, 1.3], radius=0.12)  # 18 cm above the top
        c.step(5)
        alone = finest(c)
        ch = c.haptic_open(2, focus=0)
        c.step(5)
        zero = finest(c)
        r0 = c.haptic_open(2)  # focus left out: kept
        r = c.haptic_open(2, focus=3)
        c.step(5)
        on = finest(c)
        c.step(5)
        kept = finest(c)
        c.haptic_close(2)
        c.step(30)
        after = finest(c)
    print(f"# focus: finest-level active nodes, criterion alone {alone}, focus 0 {zero}, focus 3 {on} "
          f"then {kept}, closed {after}")
    check(ch["focus"] == 0 and r0["focus"] == 0 and r["focus"] == 3,
          f"the reply gives the channel's focus, kept when left out ({ch['focus']}, {r0['focus']}, {r['focus']})")
    check(alone == 0 and zero == 0, f"no focus: the body at rest refines nothing ({alone}, {zero} nodes)")
    check(on > 0 and kept >= on, f"focus 3: the finest level about the tool ({on}, then {kept} nodes)")
    check(after == 0, f"the channel closed: the criterion alone merges them ({after} nodes)")


# ---------------------------------------------------------------- bad input and the flood
def test_input(url):
    c = SquishClient.connect(url, client="haptic-input")
    opened = c.open("cube-poke")
    c.tool(id=1, shape="sphere", pos=[0.5, 0.5, 1.3], active=False)
    c.tool(id=2, shape="sphere", pos=[0.5, 0.5, 1.07], radius=0.12)
    v = SquishClient.connect(url, client="haptic-viewer", role="view")
    v.join(opened["session"], role="view")
    try:
        c.haptic_open(9)
        check(False, "haptic on an unknown tool is refused")
    except SquishError as e:
        check(e.code == "unknown_tool", f"haptic on an unknown tool: {e.code}")
    try:
        v.haptic_open(2)
        check(False, "a viewer cannot open a channel")
    except SquishError as e:
        check(e.code == "not_controller", f"a viewer opening a channel: {e.code}")
    try:
        c.request({"type": "haptic", "tool": 2, "stiffness": -1})
        check(False, "negative coupling stiffness is refused")
    except SquishError as e:
        check(e.code == "out_of_range" and "haptic.stiffness" in e.message, f"negative stiffness: {e.code}")
    try:
        c.request({"type": "haptic", "tool": 2, "device_mass": 0})
        check(False, "a device mass of 0 is refused")
    except SquishError as e:
        check(e.code == "out_of_range" and "haptic.device_mass" in e.message, f"device mass 0: {e.code}")
    for bad in (-1, 101, "wide"):
        try:
            c.request({"type": "haptic", "tool": 2, "focus": bad})
            check(False, f"focus {bad!r} is refused")
        except SquishError as e:
            want = "bad_field" if isinstance(bad, str) else "out_of_range"
            check(e.code == want and "haptic.focus" in e.message, f"focus {bad!r}: {e.code}: {e.message}")
    try:
        c.request({"type": "haptic", "tool": 2, "spring": 1})
        check(False, "an unknown field is refused")
    except SquishError as e:
        check(e.code == "bad_field" and "spring" in e.message, f"an unknown field: {e.code}")
    r = c.haptic_open(2)
    ch = r["channel"]
    check(r["max_rate"] == 2000 and r["version"] == 1 and r["device_mass"] == 0.2 and r["focus"] == 3,
          "the reply gives version 1, max_rate 2000, the default device_mass 0.2 kg and focus 3")
    # the coupling spring, not given, is the measured safe side for the device's mass at the
    # scene's 50 Hz: 50 x 50 x 0.2 = 500 N/m, following a later device_mass; a given one is kept
    heavier = c.haptic_open(2, device_mass=0.4, damping=0)
    kept = c.haptic_open(2)
    given = c.haptic_open(2, stiffness=800)
    lighter = c.haptic_open(2, device_mass=0.2, damping=2)
    check(r["stiffness"] == 500 and r["stiffness_safe"] == 500,
          f"the default coupling is the safe side for 0.2 kg at 50 Hz ({r['stiffness']}, safe {r['stiffness_safe']} N/m)")
    check(heavier["stiffness"] == 1000 and heavier["stiffness_safe"] == 1000 and kept["stiffness"] == 1000,
          f"a spring not given follows the device's mass (0.4 kg: {heavier['stiffness']}, then {kept['stiffness']} N/m)")
    check(given["stiffness"] == 800 and lighter["stiffness"] == 800 and lighter["stiffness_safe"] == 500,
          f"a given spring is kept ({given['stiffness']}, {lighter['stiffness']} N/m, safe {lighter['stiffness_safe']})")
    check(kept["damping"] == 0 and lighter["damping"] == 2,
          f"a damping of 0 is kept when left out ({kept['damping']}, then {lighter['damping']} N s/m)")
    time.sleep(0.1)
    f = c.haptic(ch, [0.5, 0.5, 1.07], 0.0)
    check(f["contact"] and f["force"][2] > 0, f"a pose in contact gets an upward force ({f['force'][2]:.2f} N)")
    errors = []
    c.on("servererror", errors.append)
    verrors = []
    v.on("servererror", verrors.append)
    # NaN, out of bounds: dropped, counted, one error each
    c.send_raw(encode_pose(ch, 100, 0.1, (float("nan"), 0.5, 1.0)))
    time.sleep(1.1)  # errors are sent at most once a second per channel
    c.send_raw(encode_pose(ch, 101, 0.1, (0.5, 0.5, 5000.0)))
    # a viewer sending on the controller's channel, a malformed message
    v.send_raw(encode_pose(ch, 102, 0.1, (0.5, 0.5, 1.0)))
    v.send_raw(b"SQHP\x01\x00")
    time.sleep(0.3)
    codes = [e["code"] for e in errors]
    check(codes.count("bad_pose") == 2, f"NaN and out-of-bounds poses: errors {codes}")
    check(any("5000" in e["message"] for e in errors), "the error names the out-of-bounds value")
    vcodes = [e["code"] for e in verrors]
    check("bad_channel" in vcodes, f"a pose on a channel the client does not own: {vcodes}")
    st = c.stats()["haptic"]
    check(st["channels"][0]["dropped_bad"] == 2 and st["bad_channel"] >= 1,
          f"drops counted in stats.haptic: {st}")
    # the flood: 20 kHz for 2 s on the controller's channel while the viewer counts frames
    pose = [encode_pose(ch, 1000 + k, 1 + k * 5e-5, (0.5, 0.5, 1.07)) for k in range(40000)]
    b0, tb = v.frames_received, time.time()
    vs0 = v.stats()
    time.sleep(2.0)  # the viewer's frame rate without the flood, the baseline
    base = (v.frames_received - b0) / (time.time() - tb)
    f0 = v.frames_received
    got = []
    c.on("haptic", got.append)
    t0 = time.time()

    async def flood():
        for k in range(0, len(pose), 100):
            for m in pose[k:k + 100]:
                await c._ws.send(m)
            ahead = t0 + (k + 100) * 5e-5 - time.time()
            if ahead > 0:
                await asyncio.sleep(ahead)
    asyncio.run_coroutine_threadsafe(flood(), c._loop).result(60)
    elapsed = time.time() - t0
    time.sleep(0.3)
    fr = (v.frames_received - f0) / (time.time() - t0)
    st = c.stats()["haptic"]["channels"][0]
    vs1 = v.stats()
    rate = len(pose) / elapsed
    # which side a low frame rate comes from: frames the session did not step in time (its
    # deadline misses: a loaded machine) or frames the server stepped but skipped for this
    # viewer (a newer one replaced an unsent one: the viewer did not read, or the service
    # thread did not write); both counted from before the baseline to after the flood
    print(f"# flood: {len(pose)} poses in {elapsed:.2f} s ({rate:.0f}/s), answered {len(got)}, "
          f"dropped_rate {st['dropped_rate']}, viewer {fr:.1f} frames/s; since the baseline the session "
          f"stepped {vs1['frame'] - vs0['frame']} frames, {vs1['deadline_misses'] - vs0['deadline_misses']} "
          f"of them late (deadline misses), and skipped {vs1['skipped'] - vs0['skipped']} for the viewer; "
          f"load {os.getloadavg()[0]:.2f}")
    check(rate > 15000, f"the flood ran at {rate:.0f} poses/s (> 15 kHz)")
    check(st["dropped_rate"] > 0 and len(got) <= 2000 * (elapsed + 0.5) + 100,
          f"the channel answered at most max_rate ({len(got)} in {elapsed:.2f} s), dropped {st['dropped_rate']}")
    check(fr > 0.85 * base, f"the viewer kept its frame rate during the flood: {fr:.1f} frames/s "
                            f"(> 85 % of the {base:.1f} before it)")
    rl = [e for e in errors if e["code"] == "rate_limited"]
    check(1 <= len(rl) <= elapsed + 2, f"rate errors sent at most once a second ({len(rl)})")
    # the session still steps and answers (once the server has read the flood's backlog and
    # the bucket has refilled: a pose dropped then gets no answer, so ask up to 5 times)
    f = None
    for attempt in range(5):
        time.sleep(0.5)
        try:
            f = c.haptic(ch, [0.5, 0.5, 1.07], 10.0 + attempt, timeout=1.0)
            break
        except TimeoutError:
            pass
    check(f is not None and f["contact"], "after the flood the channel answers")
    c.haptic_close(2)
    errors.clear()
    c.send_raw(encode_pose(ch, 5, 11.0, (0.5, 0.5, 1.07)))
    time.sleep(0.3)
    check([e["code"] for e in errors] == ["bad_channel"], "a pose on a closed channel: bad_channel")
    v.close()
    c.close()


if __name__ == "__main__":
    what = sys.argv[1]
    if what == "scene":
        scene_at_rate(sys.argv[3], float(sys.argv[2]))
        scene_coupled(sys.argv[3])
        sys.exit(0)
    if what == "device-rate":
        test_device_rate(sys.argv[2], float(sys.argv[3]))
    else:
        {"device": test_device, "focus": test_focus, "scene-haptic": test_scene_haptic,
         "input": test_input}[what](sys.argv[2])
    print(f"haptic-{what}: {passed} passed, {failed} failed")
    sys.exit(1 if failed else 0)
