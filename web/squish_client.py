"""squish_client - a Python client for the squish protocol v1 (docs/protocol.md).

For test scripts and bots. Needs the standard library and the `websockets` package (Debian:
`apt-get install python3-websockets`, then run with /usr/bin/python3). The calls mirror the
JavaScript client web/squish-client.js; they block, and a background thread reads the socket:

    from squish_client import SquishClient, SquishError
    c = SquishClient.connect("ws://127.0.0.1:8080/ws", role="control")
    opened = c.open("paper-cube")            # topologies are in c.bodies
    c.tool(id=1, shape="grab", pos=[0.5, 0.5, 1.0], radius=0.1)
    if c.welcome["lockstep"]:
        c.step(10)                           # returns after the 10 frames arrived
    f = c.frames[0]                          # newest frame of body 0
    print(f.frame, f.positions[0], f.tools[0]["force"])
    try:
        c.set(material={"nu": 0.7})
    except SquishError as e:
        print(e.code)                        # "out_of_range"
    c.close()

Frames, topologies and node lists are decoded into plain lists and tuples (no numpy).
Callbacks given to `on()` run on the reader thread, in arrival order.
"""

import asyncio
import json
import struct
import sys
import threading
import zlib
from array import array
from concurrent.futures import Future, TimeoutError as FutureTimeout

try:
    import websockets
except ImportError as _e:  # pragma: no cover - depends on the machine
    raise ImportError(
        "squish_client needs the websockets package: on Debian `apt-get install python3-websockets` "
        "and run the script with /usr/bin/python3 (or `pip install websockets`)") from _e

__all__ = ["SquishClient", "SquishError", "encode_pose", "decode_force", "decode_binary", "decode_header", "Frame", "Topology",
           "Nodes", "KIND_TOPOLOGY", "KIND_FRAME", "KIND_NODES", "HEADER_BYTES"]

HEADER_BYTES = 64
KIND_TOPOLOGY, KIND_FRAME, KIND_NODES = 1, 2, 3
TOOL_SHAPES = ("sphere", "box", "grab")
_HEADER = struct.Struct("<4sHBBIIdII3f3fII")
_TOOL = struct.Struct("<IBBH3ff3f")
_NODE = struct.Struct("<3fB")
# haptic channel (docs/protocol.md, "Haptic channel"): pose in (48 bytes), force out (104 bytes)
HAPTIC_MAGIC = b"SQHP"
HAPTIC_VERSION = 1
_HPOSE = struct.Struct("<4sHBBIId3d")
_HFORCE = struct.Struct("<4sHBBIIIId3d3d3d")
HAPTIC_CONTACT, HAPTIC_RELEASED, HAPTIC_NO_MODEL = 1, 2, 4


def encode_pose(channel, seq, t, pos):
    """The 48-byte binary pose message of a haptic channel."""
    return _HPOSE.pack(HAPTIC_MAGIC, HAPTIC_VERSION, 1, 0, channel, seq & 0xFFFFFFFF, float(t),
                       float(pos[0]), float(pos[1]), float(pos[2]))


def decode_force(buf):
    """A 104-byte haptic force message as a dict; ValueError names what is wrong."""
    if len(buf) != _HFORCE.size:
        raise ValueError(f"haptic force message of {len(buf)} bytes, expected {_HFORCE.size}")
    (magic, version, kind, flags, channel, seq, frame, _r, t, fx, fy, fz, tx, ty, tz,
     px, py, pz) = _HFORCE.unpack(buf)
    if magic != HAPTIC_MAGIC or version != HAPTIC_VERSION or kind != 2:
        raise ValueError(f"haptic force message: magic {magic!r} version {version} kind {kind}")
    return {"channel": channel, "seq": seq, "frame": frame, "flags": flags, "t": t,
            "contact": bool(flags & HAPTIC_CONTACT), "released": bool(flags & HAPTIC_RELEASED),
            "no_model": bool(flags & HAPTIC_NO_MODEL),
            "force": (fx, fy, fz), "torque": (tx, ty, tz), "tool": (px, py, pz)}


class SquishError(Exception):
    """An `error` reply of the server: `code` is the protocol's error code, `reply` the message."""

    def __init__(self, reply):
        super().__init__(f"{reply.get('code')}: {reply.get('message')}")
        self.code = reply.get("code")
        self.message = reply.get("message")
        self.reply = reply


def decode_header(buf):
    """The 64-byte header of a binary message as a dict; ValueError names what is wrong."""
    if len(buf) < HEADER_BYTES:
        raise ValueError(f"binary message of {len(buf)} bytes is shorter than the {HEADER_BYTES}-byte header")
    (magic, version, kind, flags, body, frame, time, count0, count1, ox, oy, oz, sx, sy, sz,
     raw_bytes, zbytes) = _HEADER.unpack_from(buf, 0)
    if magic != b"SQSH":
        raise ValueError(f"binary message: bad magic {magic!r} (expected b'SQSH')")
    if version != 1:
        raise ValueError(f"binary message: protocol version {version}, this client reads version 1")
    if kind not in (1, 2, 3):
        raise ValueError(f"binary message: unknown kind {kind}")
    if HEADER_BYTES + zbytes > len(buf):
        raise ValueError(f"binary message: header says {zbytes} compressed bytes, only {len(buf) - HEADER_BYTES} follow")
    return {"version": version, "kind": kind, "flags": flags, "body": body, "frame": frame,
            "time": time, "count0": count0, "count1": count1, "offset": (ox, oy, oz),
            "scale": (sx, sy, sz), "raw_bytes": raw_bytes, "zbytes": zbytes}


def _typed(code, data):
    a = array(code)
    if a.itemsize != {"f": 4, "H": 2, "I": 4}[code]:
        a = array("L" if code == "I" else code)
    a.frombytes(data)
    if sys.byteorder != "little":
        a.byteswap()
    return a


def _triples(flat):
    return [tuple(flat[i:i + 3]) for i in range(0, len(flat), 3)]


class Topology:
    """A body's surface: `rest` [(x, y, z)] rest positions, `triangles` [(a, b, c)] indices."""

    def __init__(self, header, raw):
        n, t = header["count0"], header["count1"]
        self.header = header
        self.body = header["body"]
        self.rest = _triples(_typed("f", raw[:12 * n]))
        self.triangles = _triples(_typed("I", raw[12 * n:12 * n + 12 * t]))
        for tri in self.triangles:
            if max(tri) >= n:
                raise ValueError(f"topology of body {self.body}: triangle uses vertex {max(tri)} of {n}")


class Frame:
    """One simulated frame of one body.

    `frame`, `time`, `body`, `reset` (the body blew up and was reset), `tools` [{id, shape,
    active, pos, radius, force}], `levels` [level per surface vertex], `displacement` and
    `positions` [(x, y, z)] per surface vertex (positions need the body's topology; they are
    computed when first read).
    """

    def __init__(self, header, raw, rest=None):
        n = header["count0"]
        self.header = header
        self.body = header["body"]
        self.frame = header["frame"]
        self.time = header["time"]
        self.flags = header["flags"]
        self.reset = bool(header["flags"] & 1)
        self._raw = raw
        self._rest = rest
        self._disp = None
        self._pos = None
        self.levels = list(raw[6 * n:7 * n])
        self.tools = []
        for k in range(header["count1"]):
            (tid, shape, active, _r, px, py, pz, radius, fx, fy, fz) = _TOOL.unpack_from(raw, 7 * n + 36 * k)
            self.tools.append({"id": tid, "shape": TOOL_SHAPES[shape] if shape < 3 else shape,
                               "active": active != 0, "pos": (px, py, pz), "radius": radius,
                               "force": (fx, fy, fz)})

    @property
    def displacement(self):
        if self._disp is None:
            n, h = self.header["count0"], self.header
            q = _typed("H", self._raw[:6 * n])
            axes = [[h["offset"][a] + v * h["scale"][a] for v in q[a * n:(a + 1) * n]] for a in range(3)]
            self._disp = list(zip(*axes))
        return self._disp

    @property
    def positions(self):
        if self._pos is None:
            if self._rest is None:
                return None
            self._pos = [(r[0] + d[0], r[1] + d[1], r[2] + d[2]) for r, d in zip(self._rest, self.displacement)]
        return self._pos


class Nodes:
    """The simulation nodes of a body: `positions` [(x, y, z)], `levels` [int]."""

    def __init__(self, header, raw):
        self.header = header
        self.body = header["body"]
        self.positions, self.levels = [], []
        for i in range(header["count0"]):
            x, y, z, lvl = _NODE.unpack_from(raw, 13 * i)
            self.positions.append((x, y, z))
            self.levels.append(lvl)


def decode_binary(buf, rest=None):
    """Decode one binary message into a Topology, Frame or Nodes; ValueError/zlib.error on bad input."""
    h = decode_header(buf)
    raw = zlib.decompress(bytes(buf[HEADER_BYTES:HEADER_BYTES + h["zbytes"]]))
    n, c1 = h["count0"], h["count1"]
    want = {1: 12 * n + 12 * c1, 2: 7 * n + 36 * c1, 3: 13 * n}[h["kind"]]
    if len(raw) != h["raw_bytes"] or len(raw) != want:
        raise ValueError(f"binary message kind {h['kind']}: payload is {len(raw)} bytes, header says "
                         f"{h['raw_bytes']}, counts imply {want}")
    if h["kind"] == KIND_TOPOLOGY:
        return Topology(h, raw)
    if h["kind"] == KIND_FRAME:
        return Frame(h, raw, rest)
    return Nodes(h, raw)


class SquishClient:
    """A connection to `squish serve`; make one with SquishClient.connect(url, ...).

    Attributes: `welcome` (the welcome reply), `session`, `role`, `opened` (the last
    opened/joined reply), `bodies` {id: Topology}, `frames` {id: newest Frame}, `last_frame`,
    `frames_received`. Events for `on(name, fn)`: "frame", "topology", "nodes", "stats",
    "event", "control", "message" (every text message), "servererror", "close".
    """

    @classmethod
    def connect(cls, url, client="squish_client.py", role="control", token=None, origin=None,
                decode=True, timeout=10.0):
        c = cls(url, origin=origin, decode=decode, timeout=timeout)
        hello = {"type": "hello", "client": client, "role": role}
        if token is not None:
            hello["token"] = token
        c.role = role
        c.welcome = c.request(hello)
        c.role = c.welcome.get("role", role)
        return c

    def __init__(self, url, origin=None, decode=True, timeout=10.0):
        self.url = url
        self.timeout = timeout
        self.decode = decode
        self.welcome = None
        self.session = None
        self.role = None
        self.opened = None
        self.bodies = {}
        self.frames = {}
        self.last_frame = None
        self.frames_received = 0
        self.closed = False
        self._next_ref = 1
        self._pending = {}
        self._handlers = {}
        self._lock = threading.Lock()
        self._frame_cond = threading.Condition()
        self._haptic_cond = threading.Condition()
        self.haptic_forces = {}          # seq -> newest force message with that seq (bounded)
        self._haptic_seq = 0
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="squish-client", daemon=True)
        self._thread.start()
        kwargs = {"compression": None, "max_size": 256 << 20, "open_timeout": timeout}
        if origin:
            kwargs["origin"] = origin
        try:
            async def opening():
                return await websockets.connect(url, **kwargs)
            self._ws = asyncio.run_coroutine_threadsafe(opening(), self._loop).result(timeout + 1)
        except Exception as e:
            self._loop.call_soon_threadsafe(self._loop.stop)
            raise ConnectionError(f"cannot connect to {url}: {e}") from e
        self._reader = asyncio.run_coroutine_threadsafe(self._read(), self._loop)

    # ------------------------------------------------------------------ events
    def on(self, name, fn):
        """Call fn(message) for each event `name` (on the reader thread)."""
        with self._lock:
            self._handlers.setdefault(name, []).append(fn)

    def off(self, name, fn):
        with self._lock:
            if fn in self._handlers.get(name, []):
                self._handlers[name].remove(fn)

    def _emit(self, name, arg):
        with self._lock:
            fns = list(self._handlers.get(name, []))
        for fn in fns:
            fn(arg)

    def wait_for(self, pred, timeout=None, event="message"):
        """Block until an `event` emission satisfies pred; returns it (TimeoutError otherwise)."""
        fut = Future()

        def on(m):
            if not fut.done() and pred(m):
                fut.set_result(m)
        self.on(event, on)
        try:
            return fut.result(self.timeout if timeout is None else timeout)
        except FutureTimeout:
            raise TimeoutError(f"no {event} matched within {self.timeout if timeout is None else timeout} s") from None
        finally:
            self.off(event, on)

    def wait_frame(self, min_frame=0, body=0, timeout=None):
        """Block until a frame of `body` numbered >= min_frame has arrived; returns the newest."""
        wait = self.timeout if timeout is None else timeout
        with self._frame_cond:
            ok = self._frame_cond.wait_for(
                lambda: body in self.frames and self.frames[body].frame >= min_frame, wait)
            if not ok:
                raise TimeoutError(f"no frame {min_frame} of body {body} within {wait} s")
            return self.frames[body]

    # ------------------------------------------------------------------ reading
    async def _read(self):
        try:
            async for data in self._ws:
                try:
                    self._handle(data)
                except Exception as e:  # a handler's or decoder's error never stops reading
                    self._emit("problem", e)
        except websockets.exceptions.ConnectionClosed:
            pass
        finally:
            self.closed = True
            with self._lock:
                pending, self._pending = self._pending, {}
            for fut in pending.values():
                if not fut.done():
                    fut.set_exception(ConnectionError("connection closed before the reply"))
            self._emit("close", None)

    def _handle(self, data):
        if isinstance(data, bytes) and data[:4] == HAPTIC_MAGIC:
            f = decode_force(data)
            with self._haptic_cond:
                self.haptic_forces[f["seq"]] = f
                if len(self.haptic_forces) > 4096:
                    for k in sorted(self.haptic_forces)[:2048]:
                        del self.haptic_forces[k]
                self._haptic_cond.notify_all()
            self._emit("haptic", f)
            return
        if isinstance(data, bytes):
            if not self.decode:
                self._emit("binary", data)
                return
            h = decode_header(data)
            topo = self.bodies.get(h["body"])
            m = decode_binary(data, topo.rest if topo is not None and h["kind"] == KIND_FRAME else None)
            self._emit("binary", data)
            if isinstance(m, Topology):
                self.bodies[m.body] = m
                self._emit("topology", m)
            elif isinstance(m, Frame):
                with self._frame_cond:
                    self.frames_received += 1
                    self.frames[m.body] = m
                    self.last_frame = m
                    self._frame_cond.notify_all()
                self._emit("frame", m)
            else:
                self._emit("nodes", m)
            return
        msg = json.loads(data)
        self._emit("message", msg)
        if msg.get("type") == "event" and msg.get("kind") == "control" and isinstance(msg.get("you"), bool):
            self.role = "control" if msg["you"] else "view"
        ref = msg.get("ref")
        fut = None
        if ref is not None:
            with self._lock:
                fut = self._pending.pop(ref, None)
        if fut is not None:
            if msg.get("type") == "error":
                fut.set_exception(SquishError(msg))
            else:
                fut.set_result(msg)
            return
        kind = msg.get("type")
        if kind == "stats":
            self._emit("stats", msg)
        elif kind == "event":
            self._emit("event", msg)
            if msg.get("kind") == "control":
                self._emit("control", msg)
        elif kind == "error":
            self._emit("servererror", msg)

    # ------------------------------------------------------------------ requests
    def request(self, msg, timeout=None):
        """Send a request (a `ref` is added); return its reply or raise SquishError."""
        if self.closed:
            raise ConnectionError("the connection is closed")
        fut = Future()
        with self._lock:
            ref = self._next_ref
            self._next_ref += 1
            self._pending[ref] = fut
        text = json.dumps({**msg, "ref": ref})
        asyncio.run_coroutine_threadsafe(self._ws.send(text), self._loop).result(self.timeout)
        wait = self.timeout if timeout is None else timeout
        try:
            return fut.result(wait)
        except FutureTimeout:
            with self._lock:
                self._pending.pop(ref, None)
            raise TimeoutError(f"no reply to {msg.get('type')} within {wait} s") from None

    def send_raw(self, data):
        """Send text or bytes as they are (no reply matching; for tests of bad input)."""
        asyncio.run_coroutine_threadsafe(self._ws.send(data), self._loop).result(self.timeout)

    def list_scenes(self):
        """[{name, description, bodies, levels, frame_rate}]"""
        return self.request({"type": "list_scenes"})["scenes"]

    def _entered(self, reply):
        self.session = reply["session"]
        self.opened = reply
        self.role = reply.get("role", self.role)
        return reply

    def open(self, scene):
        """Open a new session of a scene; returns `opened` (topologies are in self.bodies)."""
        self.bodies.clear()
        self.frames.clear()
        return self._entered(self.request({"type": "open", "scene": scene}))

    def join(self, session, role=None):
        """Join a session (role "control" or "view", default the hello role); returns `joined`."""
        self.bodies.clear()
        self.frames.clear()
        msg = {"type": "join", "session": session}
        if role:
            msg["role"] = role
        return self._entered(self.request(msg))

    def leave(self):
        return self.request({"type": "leave"})

    def tool(self, **fields):
        """tool(id=1, shape="grab", pos=[x, y, z], radius=0.05, size=[...], active=True)"""
        return self.request({"type": "tool", **fields})

    def set(self, **fields):
        """set(body=0, material={...}, operator="fem", damping={...}, lod={...}); returns the ack."""
        return self.request({"type": "set", **fields})

    def pause(self):
        return self.request({"type": "pause"})

    def resume(self):
        return self.request({"type": "resume"})

    def reset(self, body=None):
        return self.request({"type": "reset"} if body is None else {"type": "reset", "body": body})

    def step(self, frames=1):
        """Lockstep servers: advance `frames` frames; returns `stepped` after their frames arrived."""
        return self.request({"type": "step", "frames": frames}, timeout=max(60.0, self.timeout))

    def stats(self):
        return self.request({"type": "stats"})

    def subscribe(self, **fields):
        """subscribe(stats=True, stats_hz=4, frames=True)"""
        return self.request({"type": "subscribe", **fields})

    def take_control(self, token=None):
        """Become the controller of a session that has none."""
        r = self.request({"type": "take_control"} if token is None else {"type": "take_control", "token": token})
        self.role = r.get("role", "control")
        return r

    def nodes(self, body=0):
        """Returns (reply, Nodes)."""
        got = Future()

        def on(m):
            if not got.done():
                got.set_result(m)
        self.on("nodes", on)
        try:
            reply = self.request({"type": "nodes", "body": body})
            return reply, got.result(self.timeout)
        finally:
            self.off("nodes", on)

    # ------------------------------------------------------------------ haptic channel
    def haptic_open(self, tool, stiffness=None, damping=None, ramp=None, device_mass=None, focus=None):
        """Open the haptic channel of tool `tool` (controller only); returns the reply
        (channel, max_rate, stiffness, damping, device_mass, focus, ramp, ...). ramp: on a
        lockstep server, each frame's substeps take the pose interpolated from the last frame's
        to the newest. device_mass: the device's moving mass, kg (the passivity controller's
        damping stays below it over the pose interval). focus: tool sizes about the tool an
        adaptive body keeps at its finest level (0: the lod's criterion alone)."""
        m = {"type": "haptic", "tool": tool}
        if focus is not None:
            m["focus"] = focus
        if device_mass is not None:
            m["device_mass"] = device_mass
        if ramp is not None:
            m["ramp"] = bool(ramp)
        if stiffness is not None:
            m["stiffness"] = stiffness
        if damping is not None:
            m["damping"] = damping
        return self.request(m)

    def haptic_close(self, tool):
        return self.request({"type": "haptic", "tool": tool, "open": False})

    def haptic_send(self, channel, pos, t):
        """Send one pose (no wait); returns its sequence number."""
        self._haptic_seq += 1
        seq = self._haptic_seq & 0xFFFFFFFF
        self.send_raw(encode_pose(channel, seq, t, pos))
        return seq

    def haptic_wait(self, seq, timeout=None):
        """The force message answering pose `seq` (TimeoutError when none comes)."""
        wait = self.timeout if timeout is None else timeout
        with self._haptic_cond:
            ok = self._haptic_cond.wait_for(lambda: seq in self.haptic_forces, wait)
            if not ok:
                raise TimeoutError(f"no haptic force for pose {seq} within {wait} s")
            return self.haptic_forces.pop(seq)

    def haptic(self, channel, pos, t, timeout=None):
        """Send a pose and return its force: {force, torque, tool, frame, flags, contact, ...}."""
        return self.haptic_wait(self.haptic_send(channel, pos, t), timeout)

    def ping(self, t=0.0):
        return self.request({"type": "ping", "t": t})

    def close(self):
        """Close the connection and stop the reader thread."""
        if not self._loop.is_running():
            return
        try:
            asyncio.run_coroutine_threadsafe(self._ws.close(), self._loop).result(self.timeout)
            self._reader.result(self.timeout)
        except Exception:
            pass
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(self.timeout)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
