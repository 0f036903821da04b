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

# one box a line: name | x y width (axes units, 0..100 x 0..67) | floor | label | detail (";" breaks the line)
COLOURS = {"entry": "#f2d7a6", "ros": "#c9d9f2", "domain": "#cfe8c9", "floor": "#e3e3e3"}
BOX_TABLE = """
nodes       |  2   50 30   | entry  | nodes/ + launch/ | launchers, launch files
cli         | 35   50 30   | entry  | scripts/         | command-line tools
api         | 68   50 30   | entry  | documented API   | trajectory_manager,; sensor_model, viewpoint
ros         |  2   34 30   | ros    | ros/             | the only place importing ROS:; nodes, executors, messages, markers
planning    | 35   34 15   | domain | planning/        | candidates, set cover,; plan, report
nbv         | 51.5 34 14   | domain | nbv/             | 2D method,; 3D loop
calibration | 67   34 15   | domain | calibration/     | flange, hand-eye
mild        | 83.5 34 14.5 | domain | mild/            | MILD model
sensors     | 35   19 20   | floor  | sensors/         | laser line, PhoXi
motion      | 57   19 20   | floor  | motion/          | IK, FCL, OMPL, TOPP-RA
station     | 79   19 19   | floor  | station/         | config, scene, URDF
common      | 35    4 63   | floor  | common/ + errors | geometry, files, config, one error root
"""


def _boxes() -> dict[str, tuple[str, str, float, float, float, str]]:
    """name -> (label, detail, x, y, width, colour), from BOX_TABLE."""
    boxes = {}
    for row in BOX_TABLE.strip().splitlines():
        name, place, floor, label, detail = (cell.strip() for cell in row.split("|"))
        x, y, width = (float(v) for v in place.split())
        boxes[name] = (label, detail.replace("; ", "\n"), x, y, width, COLOURS[floor])
    return boxes


BOXES = _boxes()
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
