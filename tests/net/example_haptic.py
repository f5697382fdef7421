"""Drive cube-poke through the haptic channel with a simulated device and print the force curve.

    /usr/bin/python3 tests/net/example_haptic.py [ws-url]     (default ws://127.0.0.1:8080/ws)

The device is a 0.2 kg mass held by a hand (a 300 N/m spring, 5 N s/m damper) whose target
presses 15 cm down onto the cube's top over 1 s and lifts again over 1 s; this script steps it
at 1 kHz, sends its position as a pose each millisecond and applies the force it gets back.
On a --lockstep server it also steps the body once every 20 poses (50 Hz). Every 50th pose
prints: time, device height, force (N), the frame of the model that answered.
"""
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "web"))
from squish_client import SquishClient  # noqa: E402

url = sys.argv[1] if len(sys.argv) > 1 else "ws://127.0.0.1:8080/ws"
DT, MASS, HAND_K, HAND_B = 0.001, 0.2, 300.0, 5.0

with SquishClient.connect(url, client="example_haptic") as c:
    c.open("cube-poke")
    c.tool(id=1, shape="sphere", pos=[0.5, 0.5, 1.3], active=False)       # the scripted finger off
    c.tool(id=2, shape="sphere", pos=[0.5, 0.5, 1.22], radius=0.12)       # the device's tool
    ch = c.haptic_open(2)
    print(f"channel {ch['channel']}: coupling {ch['stiffness']} N/m, {ch['damping']} N s/m, "
          f"up to {ch['max_rate']} poses/s")
    lockstep = c.welcome.get("lockstep")
    if lockstep:
        c.step(1)
    z, v = 1.22, 0.0
    due = time.time()
    for k in range(2000):
        t = k * DT
        hand = 1.22 - 0.15 * (t if t < 1 else 2 - t)
        f = c.haptic(ch["channel"], [0.5, 0.5, z], t)
        v += DT * (f["force"][2] + HAND_K * (hand - z) - HAND_B * v) / MASS
        z += DT * v
        if k % 50 == 0:
            print(f"t {t:5.3f} s  z {z:6.4f} m  force {f['force'][2]:7.3f} N  frame {f['frame']}")
        if lockstep and (k + 1) % 20 == 0:
            c.step(1)
        due = max(due, time.time() - DT) + DT   # one pose per millisecond, no catch-up bursts
        ahead = due - time.time()
        if ahead > 0:
            time.sleep(ahead)
    print("released")
