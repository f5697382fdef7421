#!/usr/bin/python3
"""client_test.py - the Python client (web/squish_client.py) against a real `squish serve --lockstep`.

    /usr/bin/python3 tests/net/client_test.py ws://127.0.0.1:PORT/ws

Prints one line per check and a closing "N passed, N failed".
"""
import os
import sys
import traceback
import zlib

sys.dont_write_bytecode = True  # no __pycache__ inside web/ (the server serves that directory)
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "web"))
from squish_client import SquishClient, SquishError, decode_binary, decode_header  # noqa: E402

URL = sys.argv[1]
passed, failed = 0, 0


def check(name, fn):
    global passed, failed
    try:
        fn()
        passed += 1
        print(f"ok - {name}", flush=True)
    except Skip as e:
        print(f"ok - {name} # SKIP {e}", flush=True)
    except Exception:
        failed += 1
        print(f"not ok - {name}")
        traceback.print_exc(file=sys.stdout)


def lockstep_frames():
    with SquishClient.connect(URL, client="client_test") as c:
        assert c.welcome["lockstep"] is True, c.welcome
        names = [s["name"] for s in c.list_scenes()]
        assert "paper-cube" in names, names
        o = c.open("paper-cube")
        topo = c.bodies[0]
        assert len(topo.rest) == o["bodies"][0]["surface"]["vertices"]
        assert len(topo.triangles) == o["bodies"][0]["surface"]["triangles"]
        assert all(len(v) == 3 and isinstance(v[0], float) for v in topo.rest[:5])
        # the newest frame follows `opened`; anything sent later comes after it
        c.step(1)
        n0 = c.frames_received
        r = c.step(7)
        # lockstep: every stepped frame arrives, in order, before `stepped`
        assert r["type"] == "stepped" and r["frames"] == 7, r
        assert c.frames_received - n0 == 7, (n0, c.frames_received)
        f = c.frames[0]
        assert f.frame == r["frame"], (f.frame, r["frame"])
        assert len(f.positions) == len(topo.rest) and len(f.levels) == len(topo.rest)
        # positions are rest + displacement, to float32 rounding (1e-6 m on a 1 m body)
        assert all(abs(p[a] - (q[a] + d[a])) < 1e-6
                   for p, q, d in zip(f.positions, topo.rest, f.displacement) for a in range(3))
        s = c.stats()
        assert s["frame"] == r["frame"], s


def errors_are_exceptions():
    with SquishClient.connect(URL, client="client_test") as c:
        c.open("paper-cube")
        try:
            c.set(material={"nu": 0.7})
        except SquishError as e:
            assert e.code == "out_of_range", e.code
            assert "nu" in e.message
        else:
            raise AssertionError("nu = 0.7 was accepted")
        try:
            c.open("no-such-scene")
        except SquishError as e:
            assert e.code == "unknown_scene", e.code
        else:
            raise AssertionError("an unknown scene opened")
        # the connection is still usable
        assert c.ping(3.5)["t"] == 3.5


def tool_and_feedback():
    with SquishClient.connect(URL, client="client_test") as c:
        c.open("paper-cube")
        top = max(c.bodies[0].rest, key=lambda v: v[2])
        c.tool(id=2, shape="grab", pos=list(top), radius=0.1, active=True)
        c.tool(id=2, pos=[top[0], top[1], top[2] + 0.05])
        c.step(20)
        f = c.frames[0]
        t = next(t for t in f.tools if t["id"] == 2)
        assert t["shape"] == "grab" and t["active"], t
        assert abs(t["pos"][2] - (top[2] + 0.05)) < 1e-5, t
        # the grabbed vertex followed the tool up by at least half the lift
        i = c.bodies[0].rest.index(top)
        assert f.positions[i][2] > top[2] + 0.025, f.positions[i]
        reply, nodes = c.nodes(0)
        assert reply["count"] == len(nodes.positions) > 0


def viewer_and_events():
    with SquishClient.connect(URL, client="ctl") as c, SquishClient.connect(URL, client="view", role="view") as v:
        o = c.open("paper-cube")
        j = v.join(o["session"])
        assert j["role"] == "view" and v.role == "view"
        try:
            v.tool(id=1, shape="sphere", pos=[0, 0, 3], radius=0.1)
        except SquishError as e:
            assert e.code == "not_controller", e.code
        else:
            raise AssertionError("a viewer set a tool")
        c.step(3)
        vf = v.wait_frame(c.frames[0].frame, timeout=5)
        # the same frame decodes to the same numbers in both clients
        assert vf.frame == c.frames[0].frame, (vf.frame, c.frames[0].frame)
        assert vf.positions == c.frames[0].positions


class Skip(Exception):
    """a check of a protocol feature this server does not have"""


def control_handover():
    with SquishClient.connect(URL, client="ctl") as c, SquishClient.connect(URL, client="view", role="view") as v:
        o = c.open("paper-cube")
        v.join(o["session"])
        got = []
        v.on("control", got.append)
        c.leave()
        try:
            ev = v.wait_for(lambda m: m.get("type") == "event" and m.get("kind") == "control", timeout=3)
        except TimeoutError:
            raise Skip("this server sends no event of kind control") from None
        assert ev["controller"] is False and ev["you"] is False and ev["reason"] == "left", ev
        assert got and got[0] is ev, "the 'control' event fired too"
        r = v.take_control()
        assert r["type"] == "ack" and r["request"] == "take_control" and r["role"] == "control", r
        assert v.role == "control"
        v.tool(id=3, shape="sphere", pos=[0.5, 0.5, 1.5], radius=0.1)  # now allowed
        # a second taker is refused while someone controls
        with SquishClient.connect(URL, client="late", role="view") as w:
            w.join(o["session"])
            try:
                w.take_control()
            except SquishError as e:
                assert e.code == "controller_present", e.code
            else:
                raise AssertionError("control was taken twice")


def bad_binary_is_refused():
    for buf, want in [(b"x" * 10, "shorter"), (b"XXXX" + bytes(60), "magic")]:
        try:
            decode_header(buf)
        except ValueError as e:
            assert want in str(e), e
        else:
            raise AssertionError(f"{buf!r} decoded")
    # a frame whose counts do not match its payload
    import struct
    payload = zlib.compress(bytes(7))
    h = struct.pack("<4sHBBIIdII3f3fII", b"SQSH", 1, 2, 0, 0, 1, 0.0, 2, 0, 0, 0, 0, 0, 0, 0, 7, len(payload))
    try:
        decode_binary(h + payload)
    except ValueError as e:
        assert "counts imply 14" in str(e), e
    else:
        raise AssertionError("a short frame decoded")


for name, fn in [("lockstep frames arrive before stepped and decode to plain lists", lockstep_frames),
                 ("error replies raise SquishError with the code", errors_are_exceptions),
                 ("a grab moves the surface; nodes", tool_and_feedback),
                 ("a viewer sees the controller's frames, cannot control", viewer_and_events),
                 ("control hand-over: control event, take_control, controller_present", control_handover),
                 ("broken binary messages are refused with a reason", bad_binary_is_refused)]:
    check(name, fn)
print(f"client_test.py: {passed} passed, {failed} failed")
sys.exit(1 if failed else 0)
