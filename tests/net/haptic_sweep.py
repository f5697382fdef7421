"""The haptic loop's passivity over the coupling stiffness and the device's mass (make bench).

    /usr/bin/python3 tests/net/haptic_sweep.py        (needs build/squish)

The simulated device of tests/net/haptic_test.py (a mass on a 300 N/m, 5 N s/m hand, 1 kHz,
pressing cube-poke's top, dragging, releasing) on a --lockstep server, for each frame rate of
the scene (50 Hz as shipped, 25 and 100 Hz), device mass and coupling stiffness (coupling
damping 2 N s/m, the channel told the device's mass). Prints
for each: the channel's most net work on the device against the test's tolerance (5 % of the
most it absorbed; above 1.0 the loop gave the device energy), the force's energy above 100 Hz,
and between 10 and 100 Hz (contact chatter at the frame rate), and resets. A measurement, not a
test: the stage test (tests/stages/haptic.sh) asserts the default coupling only.
"""
import os
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "web"))
import haptic_test as H  # noqa: E402
from pyserver import lockstep_server  # noqa: E402

SQUISH = os.environ.get("SQUISH", os.path.join(HERE, "..", "..", "build", "squish"))
# (frame rate Hz, ((device mass kg, (coupling stiffnesses N/m)), ...)); 50 Hz is cube-poke as shipped
SWEEP = (
    (50, ((0.1, (250.0, 500.0, 1000.0)), (0.2, (500.0, 1000.0, 2000.0)), (0.4, (1000.0, 2000.0, 3000.0)))),
    (25, ((0.1, (125.0, 250.0)), (0.2, (250.0, 500.0, 1000.0)), (0.4, (500.0, 1000.0)))),
    (100, ((0.1, (500.0, 1000.0)), (0.2, (1000.0, 2000.0, 4000.0)), (0.4, (2000.0, 4000.0)))),
)


def main():
    n = sum(len(ks) for _r, rows in SWEEP for _m, ks in rows)
    done = 0
    tmp = tempfile.mkdtemp(prefix="squish-haptic-sweep-")
    for rate, rows in SWEEP:
        scenes = os.path.join(HERE, "..", "..", "meshes", "scenes")
        if rate != 50:
            scenes = os.path.join(tmp, f"scenes-{rate}")
            H.scene_at_rate(scenes, rate)
        with lockstep_server(SQUISH, scenes) as url:
            for mass, ks in rows:
                for k in ks:
                    done += 1
                    what = f"{rate} Hz frames, device {mass} kg, coupling {k:5.0f} N/m"
                    print(f"[{done}/{n}] {what} ...", file=sys.stderr, flush=True)
                    try:
                        forces, work, resets, _st = H.run_device(url, k, 2.0, mass=mass, device_mass=mass,
                                                                 frame=1.0 / rate)
                    except TimeoutError as e:
                        print(f"{what}: no answer ({e})", flush=True)
                        continue
                    tol = H.tolerance(work)
                    fz = [f[2] for f in forces]
                    high = H.high_fraction(fz[:2000], H.DT, 100.0)
                    band = H.high_fraction(fz[:2000], H.DT, 10.0) - high
                    print(f"{what}: most net work on the device {1e3 * max(work):+.2f} mJ, "
                          f"{max(work) / tol:5.2f} x the tolerance {1e3 * tol:.2f} mJ "
                          f"({'passive' if max(work) <= tol else 'NOT passive'}); force energy above 100 Hz "
                          f"{100 * high:.1f} %, 10-100 Hz {100 * band:.1f} %; resets {len(resets)}", flush=True)


if __name__ == "__main__":
    main()
