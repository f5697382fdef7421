"""The haptic loop's passivity over the coupling stiffness and the device's mass (make bench).

    /usr/bin/python3 tests/net/haptic_sweep.py        (needs build/squish)

The simulated device of tests/net/haptic_test.py (a mass on a 300 N/m, 5 N s/m hand, 1 kHz,
pressing cube-poke's top, dragging, releasing) on a --lockstep server, for each device mass
and coupling stiffness (coupling damping 2 N s/m, the channel told the device's mass). Prints
for each: the channel's most net work on the device against the test's tolerance (5 % of the
most it absorbed; above 1.0 the loop gave the device energy), the force's energy above 100 Hz,
and between 10 and 100 Hz (contact chatter at the frame rate), and resets. A measurement, not a
test: the stage test (tests/stages/haptic.sh) asserts the default coupling only.
"""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "web"))
import haptic_test as H  # noqa: E402
from pyserver import lockstep_server  # noqa: E402

SQUISH = os.environ.get("SQUISH", os.path.join(HERE, "..", "..", "build", "squish"))
SWEEP = ((0.1, (250.0, 500.0, 1000.0)), (0.2, (500.0, 1000.0, 2000.0)), (0.4, (1000.0, 2000.0, 3000.0)))


def main():
    with lockstep_server(SQUISH, os.path.join(HERE, "..", "..", "meshes", "scenes")) as url:
        n = sum(len(ks) for _m, ks in SWEEP)
        done = 0
        for mass, ks in SWEEP:
            for k in ks:
                done += 1
                print(f"[{done}/{n}] device {mass} kg, coupling {k:.0f} N/m ...", file=sys.stderr, flush=True)
                try:
                    forces, work, resets, _st = H.run_device(url, k, 2.0, mass=mass, device_mass=mass)
                except TimeoutError as e:
                    print(f"device {mass} kg, coupling {k:5.0f} N/m: no answer ({e})", flush=True)
                    continue
                tol = 0.05 * max(1e-3, -min(work))
                fz = [f[2] for f in forces]
                high = H.high_fraction(fz[:2000], H.DT, 100.0)
                band = H.high_fraction(fz[:2000], H.DT, 10.0) - high
                print(f"device {mass} kg, coupling {k:5.0f} N/m: most net work on the device {1e3 * max(work):+.2f} mJ, "
                      f"{max(work) / tol:5.2f} x the tolerance {1e3 * tol:.2f} mJ ({'passive' if max(work) <= tol else 'NOT passive'}); "
                      f"force energy above 100 Hz {100 * high:.1f} %, 10-100 Hz {100 * band:.1f} %; resets {len(resets)}", flush=True)


if __name__ == "__main__":
    main()
