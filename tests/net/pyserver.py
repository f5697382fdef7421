"""A squish server for the Python measurement scripts (haptic_accuracy.py, haptic_sweep.py):
started on a free loopback port, waited for, stopped on leaving.

    with lockstep_server(squish, scenes_dir, extra_args) as url: ...
    load_scene(path): a scene file's JSON with its levels' paths made absolute (to be changed and
    written elsewhere)
"""
import contextlib
import json
import os
import socket
import subprocess
import time


@contextlib.contextmanager
def lockstep_server(squish, scenes, extra=()):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    srv = subprocess.Popen([squish, "serve", "--host", "127.0.0.1", "--port", str(port), "--scenes", scenes,
                            "--no-web", "--lockstep", *extra], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):  # up to 10 s on a loaded machine
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                break
            except OSError:
                if srv.poll() is not None:
                    raise RuntimeError(f"{squish} serve exited with {srv.returncode}; run it by hand to see why")
                time.sleep(0.1)
        yield f"ws://127.0.0.1:{port}/ws"
    finally:
        srv.terminate()
        srv.wait()


def load_scene(path):
    s = json.load(open(path))
    for b in s["bodies"]:
        b["levels"] = [os.path.abspath(os.path.join(os.path.dirname(path), p)) for p in b["levels"]]
    return s
