#!/usr/bin/python3
"""example_grab.py - open a scene, grab the top of the first body, pull it up, print the force.

    /usr/bin/python3 tests/net/example_grab.py [ws://127.0.0.1:8080/ws] [scene] [lift_m]

Start a server first (`make run`, or `squish serve`). With `squish serve --lockstep` the script
steps the simulation itself (10 frames per pull), else it lets the clock run 0.1 s. Uses the
client library web/squish_client.py (Debian: apt-get install python3-websockets).
"""
import math
import os
import sys
import time

sys.dont_write_bytecode = True  # no __pycache__ inside web/ (the server serves that directory)
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "web"))
from squish_client import SquishClient, SquishError  # noqa: E402

url = sys.argv[1] if len(sys.argv) > 1 else "ws://127.0.0.1:8080/ws"
lift = float(sys.argv[3]) if len(sys.argv) > 3 else 0.1

with SquishClient.connect(url, client="example_grab.py", role="control") as c:
    scenes = c.welcome["scenes"]
    scene = sys.argv[2] if len(sys.argv) > 2 else ("paper-cube" if "paper-cube" in scenes else scenes[0])
    opened = c.open(scene)
    lockstep = c.welcome["lockstep"]
    print(f'opened scene "{scene}" as session {opened["session"]}: {len(opened["bodies"])} body(ies), '
          f'{opened["bodies"][0]["surface"]["vertices"]} surface vertices, {opened["frame_rate"]} Hz'
          + (", lockstep" if lockstep else ""))

    # grab point: the highest rest surface vertex nearest to the body's centre (in x, y)
    rest = c.bodies[0].rest
    cx = sum(v[0] for v in rest) / len(rest)
    cy = sum(v[1] for v in rest) / len(rest)
    zmax = max(v[2] for v in rest)
    best = min(range(len(rest)), key=lambda i: math.hypot(rest[i][0] - cx, rest[i][1] - cy) + 10 * (zmax - rest[i][2]))
    p = rest[best]
    print(f"grabbing vertex {best} at [{p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}]")
    c.tool(id=1, shape="grab", pos=list(p), radius=0.1, active=True)

    # a refused setting raises SquishError with the protocol's code
    try:
        c.set(material={"nu": 0.7})
    except SquishError as e:
        print(f"refused as expected: {e.code}")

    # pull up in 10 steps, reading the feedback force after each
    for k in range(1, 11):
        z = p[2] + lift * k / 10
        c.tool(id=1, pos=[p[0], p[1], z])
        if lockstep:
            c.step(10)
        else:
            time.sleep(0.1)
        s = c.stats()
        fb = next((f for f in s["feedback"] if f["tool"] == 1 and f["body"] == 0), None)
        f = fb["force"] if fb else [0.0, 0.0, 0.0]
        vz = c.frames[0].positions[best][2]
        print(f"lift {z - p[2]:.3f} m: force [{f[0]:.2f}, {f[1]:.2f}, {f[2]:.2f}] N "
              f"(|F| = {math.hypot(*f):.2f} N, {fb['nodes'] if fb else 0} nodes held), "
              f"vertex z {vz:.3f} m, frame {s['frame']}")
    c.tool(id=1, active=False)
    print("released")
