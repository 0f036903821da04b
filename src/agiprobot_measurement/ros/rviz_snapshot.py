"""Off-screen rviz snapshots: rviz on a private Xvfb display, screenshots to PNG, pixel statistics.

Used by ``scripts/rviz_snapshot`` and by tests and demos that need a picture of what rviz shows.
Needs Debian's xvfb, x11-apps (xwd), imagemagick (/usr/bin/convert) and a running ROS master.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.cli import start_process_group, stop_process_group
from agiprobot_measurement.common.files import FileReadError, atomic_write
from agiprobot_measurement.ros.errors import RvizSnapshotError

__all__ = [
    "CONVERT",
    "OffscreenRviz",
    "SnapshotStats",
    "image_stats",
]

CONVERT = "/usr/bin/convert"  # /usr/local/bin/convert can be a stand-in on these machines


@dataclass(frozen=True)
class SnapshotStats:
    path: Path
    width: int
    height: int
    view_pixels: int  # pixels of the 3D view region examined
    non_background_pixels: int  # pixels in the 3D view differing from the background colour

    @property
    def non_background_fraction(self) -> float:
        return self.non_background_pixels / max(self.view_pixels, 1)


def _rviz_background(config: Path) -> np.ndarray:
    """Background colour (RGB) of an rviz config; rviz's default when not set."""
    for line in config.read_text().splitlines():
        if "Background Color:" in line:
            return np.array([int(v) for v in line.split(":", 1)[1].split(";")], dtype=float)
    return np.array([48.0, 48.0, 48.0])


def image_stats(path: Path, background_rgb: np.ndarray, top_px: int = 60, bottom_px: int = 10) -> SnapshotStats:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise RvizSnapshotError(f"cannot read screenshot {path}")
    rgb = image[:, :, ::-1].astype(float)
    view = rgb[top_px : rgb.shape[0] - bottom_px]  # skip menu/tool bars
    differs = np.abs(view - background_rgb).max(axis=2) > 12
    return SnapshotStats(Path(path), image.shape[1], image.shape[0], differs.size, int(differs.sum()))


class OffscreenRviz:
    """Start Xvfb and rviz with a config; ``grab()`` screenshots; use as a context manager."""

    def __init__(self, config: str | Path, width: int = 1024, height: int = 768, log_dir: str | Path | None = None):
        self.config = Path(config).resolve()
        if not self.config.is_file():
            raise FileReadError(f"rviz config not found: {self.config}")
        for tool in ("Xvfb", "xwd", "rviz"):
            if shutil.which(tool) is None:
                raise RvizSnapshotError(f"'{tool}' is not installed (run `make setup`)")
        if not Path(CONVERT).exists():
            raise RvizSnapshotError(f"{CONVERT} is missing (Debian package imagemagick; run `make setup`)")
        self.size = (width, height)
        self.background = _rviz_background(self.config)
        self.log_dir = Path(log_dir or tempfile.mkdtemp(prefix="rviz_snapshot_"))
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.xvfb = self.rviz = None
        self.display = None

    def __enter__(self) -> OffscreenRviz:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        read_fd, write_fd = os.pipe()
        self.xvfb = subprocess.Popen(
            [
                "nice",
                "-n",
                "15",
                "Xvfb",
                "-displayfd",
                str(write_fd),
                "-screen",
                "0",
                f"{self.size[0]}x{self.size[1]}x24",
                "-nolisten",
                "tcp",
            ],
            pass_fds=(write_fd,),
            stdout=subprocess.DEVNULL,
            stderr=(self.log_dir / "xvfb.log").open("w"),
        )
        os.close(write_fd)
        with os.fdopen(read_fd) as stream:
            number = stream.readline().strip()
        if not number:
            raise RvizSnapshotError(f"Xvfb did not start (see {self.log_dir / 'xvfb.log'})")
        self.display = f":{number}"
        env = dict(os.environ, DISPLAY=self.display)
        self.rviz = start_process_group(
            # niced: software rendering must not starve the nodes it is taking a picture of
            ["nice", "-n", "15", "rviz", "-d", str(self.config), f"__name:=rviz_snapshot_{os.getpid()}"],
            env=env,
            stdout=(self.log_dir / "rviz.log").open("w"),
            stderr=subprocess.STDOUT,
        )

    def grab(self, output: str | Path, settle_s: float = 30.0, stable_frames: int = 2) -> SnapshotStats:
        """Screenshot once the picture has stopped changing (or after ``settle_s``)."""
        output = Path(output)
        output.parent.mkdir(parents=True, exist_ok=True)
        deadline = time.monotonic() + settle_s
        previous, same = None, 0
        tmp = output.with_suffix(".tmp.png")
        while True:
            if self.rviz.poll() is not None:
                raise RvizSnapshotError(
                    f"rviz exited with code {self.rviz.returncode} (log: {self.log_dir / 'rviz.log'})"
                )
            self._screenshot(tmp)
            stats = image_stats(tmp, self.background)
            key = stats.non_background_pixels
            same = (
                same + 1 if previous is not None and key > 0 and abs(key - previous) <= 0.002 * stats.view_pixels else 0
            )
            previous = key
            if same >= stable_frames or time.monotonic() > deadline:
                break
            time.sleep(1.0)
        atomic_write(output, lambda target: shutil.move(tmp, target), suffix=".png", make_parents=True)
        return image_stats(output, self.background)

    def _screenshot(self, output: Path) -> None:
        xwd = subprocess.run(
            ["xwd", "-root", "-silent", "-display", self.display], capture_output=True, check=True, timeout=20
        )
        subprocess.run([CONVERT, "xwd:-", f"png:{output}"], input=xwd.stdout, check=True, timeout=20)

    def stop(self) -> None:
        if self.rviz is not None:
            stop_process_group(self.rviz, timeout_s=5.0)
        if self.xvfb is not None and self.xvfb.poll() is None:
            self.xvfb.terminate()
            self.xvfb.wait(timeout=5)
