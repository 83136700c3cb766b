#!/usr/bin/env python3
"""Tabulates a material's BRDF as a MERL .binary, reads it back as any MERL reader would, and checks a few cells
against Evaluate at the same directions.

    python3 tabulate_merl.py [--preset silk_shot] [--out silk_shot.binary] [--server HOST:PORT]

The reader below is the few lines of MERL's own BRDFRead.cpp in numpy, not the loomlight package's: a file any
renderer reads is what this checks. Exits 1 if a cell disagrees with Evaluate by more than --tolerance.
"""
import argparse
import os
import sys

import numpy as np

import loomlight

# MERL's channel scales: a .binary stores f / scale per channel, and readers multiply by it.
MERL_SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
# A few cells (theta_h index, theta_d index, phi_d index): near the specular peak, mid-way, near grazing.
CELLS = [(0, 0, 0), (5, 20, 45), (20, 30, 90), (40, 10, 170), (60, 20, 90), (75, 8, 90)]


def read_merl(path):
    """f (1/sr) of a MERL .binary as a (90, 90, 180, 3) float64 array: theta_h, theta_d, phi_d, RGB."""
    with open(path, "rb") as f:
        dims = np.fromfile(f, dtype="<i4", count=3)
        values = np.fromfile(f, dtype="<f8")
    if tuple(dims) != (90, 90, 180) or values.size != 3 * 90 * 90 * 180:
        sys.exit(f"{path}: not a MERL .binary (dims {tuple(dims)}, {values.size} values)")
    return (values.reshape(3, 90, 90, 180) * MERL_SCALE[:, None, None, None]).transpose(1, 2, 3, 0)


def bin_centre(i, j, k):
    """The angles (radians) of a cell's centre (MerlGrid in the .proto, docs/tabulation.md): theta_h on MERL's
    square-root bins, theta_d and phi_d on 1-degree bins."""
    return (np.radians(((i + 0.5) / 90) ** 2 * 90), np.radians(j + 0.5), np.radians(k + 0.5))


def directions(theta_h, theta_d, phi_d, phi_h):
    """wi and wo for half/difference angles (Rusinkiewicz): the difference vector d, in the frame where the half
    vector is +z, is rotated by theta_h about y and then by phi_h about z (the inverse of MERL's
    std_coords_to_half_diff_coords); wo is wi mirrored about the half vector."""
    d = np.array([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)])

    def to_world(v):
        x = v[0] * np.cos(theta_h) + v[2] * np.sin(theta_h)   # about y by theta_h
        z = -v[0] * np.sin(theta_h) + v[2] * np.cos(theta_h)
        y = v[1]
        return np.array([x * np.cos(phi_h) - y * np.sin(phi_h), x * np.sin(phi_h) + y * np.cos(phi_h), z])

    return to_world(d), to_world(d * [-1, -1, 1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="silk_shot")
    parser.add_argument("--out", help="the .binary to write (default PRESET.binary)")
    parser.add_argument("--server", default=os.environ.get("LOOMLIGHT_SERVER", "127.0.0.1:50051"))
    parser.add_argument("--tolerance", type=float, default=1e-3, help="largest relative difference accepted")
    args = parser.parse_args()
    out = args.out or f"{args.preset}.binary"

    with loomlight.Client(args.server, timeout=600) as client:
        shown = []

        def progress(done, total):  # called per chunk (at most 4 MiB each): report every tenth
            tenth = 10 * done // total
            if not shown or tenth > shown[-1]:
                shown.append(tenth)
                print(f"tabulating {args.preset}: {10 * tenth}%", file=sys.stderr, flush=True)

        table = client.tabulate(args.preset, "merl", path=out, progress=progress)
        print(f"{out}: {table.model}, dims {table.dims}, {table.queries_per_cell} phi_h per cell, "
              f"{table.total_seconds:.1f} s on the server, {os.path.getsize(out)} bytes")

        f = read_merl(out)
        # A cell is the mean of f over queries_per_cell half-vector azimuths phi_h = s 360 / count: evaluate the
        # same directions in one call and average them likewise.
        count = table.queries_per_cell
        wi, wo = zip(*(directions(*bin_centre(*cell), 2 * np.pi * s / count) for cell in CELLS for s in range(count)))
        expected = client.evaluate(args.preset, np.array(wi), np.array(wo)).reshape(len(CELLS), count, 3).mean(axis=1)

    print("theta_h  theta_d  phi_d   .binary (r, g, b)                  evaluate (r, g, b)                 rel. diff")
    worst = 0.0
    for cell, want in zip(CELLS, expected):
        got = f[cell]
        # Relative to the cell's largest channel, so that a near-zero channel does not blow the ratio up.
        difference = float(np.max(np.abs(got - want)) / max(np.max(np.abs(want)), 1e-12))
        worst = max(worst, difference)
        angles = np.degrees(bin_centre(*cell))
        print(f"{angles[0]:7.3f}  {angles[1]:7.1f}  {angles[2]:5.1f}   "
              f"{' '.join(f'{v:10.5g}' for v in got)}   {' '.join(f'{v:10.5g}' for v in want)}   {difference:.2e}")
    print(f"largest relative difference {worst:.2e} (tolerance {args.tolerance:g})")
    return 0 if worst <= args.tolerance else 1


if __name__ == "__main__":
    sys.exit(main())
