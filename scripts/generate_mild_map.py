#!/usr/bin/env python3
"""Writes the MILD's example map (config/maps/mild_lab.pgm + .yaml, map_server format).

The map is configuration shipped with the package; this script only documents how it was drawn and redraws it:

  scripts/generate_mild_map.py [--output-dir config/maps]

A 12 m x 9 m lab at 0.05 m/cell, origin (-1, -1): walls around a free room, an inner wall with a 2.5 m wide
passage at the top (paths from the left half to the right half detour through it), a table, a closed box room
whose free inside cannot be reached, and an unexplored (unknown) corner. Rectangles are in metres, map frame.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.cli import run_main
from agiprobot_measurement.common.files import write_output

RESOLUTION_M = 0.05
ORIGIN_M = (-1.0, -1.0)
SIZE_M = (12.0, 9.0)
FREE, OCCUPIED, UNKNOWN = 254, 0, 205  # map_server trinary: white free, black occupied, grey unknown

# (value, x_min, x_max, y_min, y_max), drawn in order
RECTANGLES = [
    (OCCUPIED, -0.6, 10.6, -0.6, 7.6),  # outer wall ring: filled, then the inside is cleared
    (FREE, -0.5, 10.5, -0.5, 7.5),
    (OCCUPIED, 4.95, 5.05, -0.5, 5.0),  # inner wall; passage for y in [5.0, 7.5]
    (OCCUPIED, 2.0, 3.0, 4.0, 5.0),  # table
    (OCCUPIED, 7.0, 9.0, 2.0, 4.0),  # closed box room ...
    (FREE, 7.1, 8.9, 2.1, 3.9),  # ... with an unreachable free inside
    (UNKNOWN, 9.0, 10.5, -0.5, 1.0),  # unexplored corner
]


def draw() -> np.ndarray:
    width, height = round(SIZE_M[0] / RESOLUTION_M), round(SIZE_M[1] / RESOLUTION_M)
    image = np.full((height, width), UNKNOWN, dtype=np.uint8)
    # cell centres in the map frame; image row 0 is the top edge (largest y), as map_server reads it
    xs = ORIGIN_M[0] + (np.arange(width) + 0.5) * RESOLUTION_M
    ys = ORIGIN_M[1] + (height - 1 - np.arange(height) + 0.5) * RESOLUTION_M
    for value, x0, x1, y0, y1 in RECTANGLES:
        rows = (ys >= y0) & (ys <= y1)
        cols = (xs >= x0) & (xs <= x1)
        image[np.ix_(rows, cols)] = value
    return image


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output-dir", default=str(Path(__file__).resolve().parents[1] / "config" / "maps"))
    parser.add_argument("--name", default="mild_lab")
    args = parser.parse_args()
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    image = draw()
    pgm = out / f"{args.name}.pgm"
    header = f"P5\n# {args.name}: drawn by scripts/generate_mild_map.py\n{image.shape[1]} {image.shape[0]}\n255\n"
    write_output(pgm, header.encode() + image.tobytes())
    write_output(
        out / f"{args.name}.yaml",
        "# map_server map of the MILD example lab (drawn by scripts/generate_mild_map.py).\n"
        "# resolution: m/cell; origin: [x m, y m, yaw rad] of the lower-left cell's corner in the map frame.\n"
        f"image: {pgm.name}\n"
        f"resolution: {RESOLUTION_M}\n"
        f"origin: [{ORIGIN_M[0]}, {ORIGIN_M[1]}, 0.0]\n"
        "negate: 0\n"
        "occupied_thresh: 0.65\n"
        "free_thresh: 0.196\n",
    )
    print(f"map: {pgm} ({image.shape[1]} x {image.shape[0]} cells)")
    return 0


if __name__ == "__main__":
    sys.exit(run_main(main))
