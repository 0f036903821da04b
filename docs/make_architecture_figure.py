#!/usr/bin/env python3
"""Draw docs/images/architecture.png: the package's floors, entry points on top, arrows pointing down only.

python docs/make_architecture_figure.py [-o docs/images/architecture.png]
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

HERE = Path(__file__).resolve().parent

# (label, detail, x, y, width, colour); units are the axes' (0..100 x 0..60)
ENTRY, ROS, DOMAIN, FLOOR = "#f2d7a6", "#c9d9f2", "#cfe8c9", "#e3e3e3"
BOXES = {
    "nodes": ("nodes/ + launch/", "launchers, launch files", 2, 50, 30, ENTRY),
    "cli": ("scripts/", "command-line tools", 35, 50, 30, ENTRY),
    "api": ("documented API", "trajectory_manager,\nsensor_model, viewpoint", 68, 50, 30, ENTRY),
    "ros": ("ros/", "the only place importing ROS:\nnodes, executors, messages, markers", 2, 34, 30, ROS),
    "planning": ("planning/", "candidates, set cover,\nplan, report", 35, 34, 15, DOMAIN),
    "nbv": ("nbv/", "2D method,\n3D loop", 51.5, 34, 14, DOMAIN),
    "calibration": ("calibration/", "flange, hand-eye", 67, 34, 15, DOMAIN),
    "mild": ("mild/", "MILD model", 83.5, 34, 14.5, DOMAIN),
    "sensors": ("sensors/", "laser line, PhoXi", 35, 19, 20, FLOOR),
    "motion": ("motion/", "IK, FCL, OMPL, TOPP-RA", 57, 19, 20, FLOOR),
    "station": ("station/", "config, scene, URDF", 79, 19, 19, FLOOR),
    "common": ("common/ + errors", "geometry, files, config, one error root", 35, 4, 63, FLOOR),
}
ARROWS = [
    ("nodes", "ros"),
    ("cli", "planning"),
    ("cli", "nbv"),
    ("api", "planning"),
    ("ros", "planning"),
    ("ros", "sensors"),
    ("planning", "sensors"),
    ("planning", "motion"),
    ("nbv", "motion"),
    ("calibration", "motion"),
    ("mild", "station"),
    ("motion", "station"),
    ("sensors", "common"),
    ("station", "common"),
]
HEIGHT = 11


def draw(path: Path) -> None:
    fig, ax = plt.subplots(figsize=(10, 6))
    ax.set_xlim(0, 100)
    ax.set_ylim(0, 67)
    ax.axis("off")
    for label, detail, x, y, width, colour in BOXES.values():
        ax.add_patch(
            FancyBboxPatch(
                (x, y), width, HEIGHT, boxstyle="round,pad=0.3", facecolor=colour, edgecolor="#555555", linewidth=1
            )
        )
        ax.text(x + width / 2, y + HEIGHT - 3, label, ha="center", va="center", fontsize=10, weight="bold")
        ax.text(x + width / 2, y + 3.8, detail, ha="center", va="center", fontsize=7.5)
    for start, end in ARROWS:
        _, _, x0, y0, w0, _ = BOXES[start]
        _, _, x1, y1, w1, _ = BOXES[end]
        if y0 == y1:  # side by side: from the right edge to the left edge
            tail, head = (x0 + w0 + 0.4, y0 + HEIGHT / 2), (x1 - 0.4, y1 + HEIGHT / 2)
        else:
            tail, head = (x0 + w0 / 2, y0 - 0.3), (x1 + w1 / 2, y1 + HEIGHT + 0.3)
        ax.add_patch(
            FancyArrowPatch(
                tail,
                head,
                arrowstyle="-|>",
                mutation_scale=10,
                color="#444444",
                linewidth=0.8,
            )
        )
    ax.text(
        50,
        66.5,
        "agiprobot_measurement: entry points on top, ROS only in ros/, arrows point down",
        ha="center",
        va="top",
        fontsize=11,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=HERE / "images" / "architecture.png")
    draw(parser.parse_args().output)


if __name__ == "__main__":
    main()
