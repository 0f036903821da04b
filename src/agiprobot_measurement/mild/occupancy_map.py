"""Occupancy grid of the MILD's world: a map_server map (PGM + YAML), its inflation, position checks and grid paths.

ROS-free. The occupancy values follow nav_msgs/OccupancyGrid: -1 unknown, 0 free ... 100 occupied, rows from the
map origin upwards (row 0 = lowest y), columns along x. The inflated map ("costmap") adds costmap_2d-style costs
around obstacles (99 within the inscribed radius, then exponentially decaying out to the inflation radius, on the
0..100 scale of asr_robot_model_services' MapHelper) and keeps unknown cells unknown. A position is allowed when its
inflated value lies within [0, colThresh]; unknown cells and cells outside the map are never allowed.

Shortest paths run on the allowed cells with scikit-image's minimum-cost-path search (``MCP_Geometric``: 8-connected,
diagonal steps cost sqrt(2) cells). The cell path is then straightened by line of sight ("string pulling"): from
each kept point the path jumps to the farthest later cell that a straight segment over allowed cells reaches, so
its length and heading changes do not carry the grid's staircase. Lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agiprobot_measurement.station import ConfigError, read_yaml

__all__ = [
    "INSCRIBED",
    "LETHAL",
    "UNKNOWN",
    "GridPlanner",
    "OccupancyMap",
    "inflate",
    "occupancy_from_image",
    "polyline_length",
    "read_pgm",
]

UNKNOWN = -1
LETHAL = 100
INSCRIBED = 99


def read_pgm(path: Path) -> np.ndarray:
    """8-bit greyscale image of a binary (P5) or ASCII (P2) PGM file, row 0 = top of the image."""
    data = path.read_bytes()
    tokens: list[bytes] = []
    position = 0
    # the header is four whitespace-separated tokens (magic, width, height, maxval) with '#' comments between
    while len(tokens) < 4:
        while position < len(data) and data[position : position + 1].isspace():
            position += 1
        if data[position : position + 1] == b"#":
            position = data.index(b"\n", position) + 1
            continue
        start = position
        while position < len(data) and not data[position : position + 1].isspace():
            position += 1
        tokens.append(data[start:position])
    magic, width, height, maxval = tokens[0], int(tokens[1]), int(tokens[2]), int(tokens[3])
    if magic == b"P5":
        if maxval > 255:
            raise ConfigError(f"{path}: 16-bit PGM is not supported")
        pixels = np.frombuffer(data, dtype=np.uint8, count=width * height, offset=position + 1)
    elif magic == b"P2":
        pixels = np.array(data[position:].split()[: width * height], dtype=np.int64)
    else:
        raise ConfigError(f"{path}: not a PGM file (magic {magic!r})")
    if pixels.size != width * height:
        raise ConfigError(f"{path}: truncated image ({pixels.size} of {width * height} pixels)")
    return (pixels.reshape(height, width).astype(np.float64) * (255.0 / maxval)).round().astype(np.uint8)


def _read_image(path: Path) -> np.ndarray:
    if not path.is_file():
        raise ConfigError(f"{path}: map image not found")
    if path.suffix.lower() == ".pgm":
        return read_pgm(path)
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ConfigError(f"{path}: cannot read the map image")
    return image


def occupancy_from_image(
    image: np.ndarray, negate: bool, occupied_thresh: float, free_thresh: float, mode: str = "trinary"
) -> np.ndarray:
    """map_server's interpretation of a greyscale image (row 0 = top) as OccupancyGrid values (row 0 = bottom)."""
    image = np.asarray(image)
    if mode == "raw":
        values = image.astype(np.int16)
        values[values > 100] = UNKNOWN
        return np.flipud(values).astype(np.int8)
    if mode != "trinary":
        raise ConfigError(f"map mode '{mode}' is not supported (trinary or raw)")
    occupancy_probability = image / 255.0 if negate else (255.0 - image) / 255.0
    values = np.full(image.shape, UNKNOWN, dtype=np.int8)
    values[occupancy_probability > occupied_thresh] = LETHAL
    values[occupancy_probability < free_thresh] = 0
    return np.flipud(values)


def inflate(
    occupancy: np.ndarray,
    resolution_m: float,
    inscribed_radius_m: float,
    inflation_radius_m: float,
    cost_scaling_per_m: float,
) -> np.ndarray:
    """costmap_2d's inflation translated to the 0..100 scale; unknown cells stay unknown."""
    from scipy.ndimage import distance_transform_edt

    occupied = occupancy == LETHAL
    if occupied.any():
        distance_m = distance_transform_edt(~occupied) * resolution_m
    else:
        distance_m = np.full(occupancy.shape, np.inf)
    # costmap_2d: 252 * exp(-k (d - r_inscribed)) on its 0..254 scale, then MapHelper's table 1 + 97 (c - 1) / 251
    raw = np.floor(252.0 * np.exp(-cost_scaling_per_m * np.maximum(distance_m - inscribed_radius_m, 0.0)))
    translated = np.where(raw >= 1, 1 + (97 * (raw - 1)) // 251, 0)
    cost = np.where(distance_m <= inflation_radius_m, translated, 0).astype(np.int16)
    cost[distance_m <= inscribed_radius_m] = INSCRIBED
    cost[occupied] = LETHAL
    cost[occupancy == UNKNOWN] = UNKNOWN
    return cost.astype(np.int8)


@dataclass
class OccupancyMap:
    """A 2-D occupancy grid in the map frame and its inflated version."""

    occupancy: np.ndarray  # int8 (rows, cols), row 0 at the origin's y
    resolution_m: float
    origin_xy_m: np.ndarray
    origin_yaw_rad: float = 0.0
    inscribed_radius_m: float = 0.3
    inflation_radius_m: float = 0.6
    cost_scaling_per_m: float = 5.0
    source: Path | str | None = None  # the map file, or the topic it came from
    costmap: np.ndarray = field(init=False, repr=False)
    _planners: dict = field(init=False, repr=False, default_factory=dict)

    def __post_init__(self) -> None:
        self.occupancy = np.asarray(self.occupancy, dtype=np.int8)
        self.origin_xy_m = np.asarray(self.origin_xy_m, dtype=float)
        if self.occupancy.ndim != 2 or self.occupancy.size == 0:
            raise ConfigError(f"{self.source or 'map'}: the occupancy grid must be a non-empty 2-D array")
        if not (self.resolution_m > 0 and math.isfinite(self.resolution_m)):
            raise ConfigError(f"{self.source or 'map'}: resolution must be a positive number of metres per cell")
        if not 0 <= self.inscribed_radius_m <= self.inflation_radius_m:
            raise ConfigError(
                f"need 0 <= inscribed radius ({self.inscribed_radius_m} m) <= inflation radius "
                f"({self.inflation_radius_m} m)"
            )
        self.costmap = inflate(
            self.occupancy,
            self.resolution_m,
            self.inscribed_radius_m,
            self.inflation_radius_m,
            self.cost_scaling_per_m,
        )
        c, s = math.cos(self.origin_yaw_rad), math.sin(self.origin_yaw_rad)
        self._rotation = np.array([[c, -s], [s, c]])
        # a border of unknown cells lets the IK's hot path clip indices instead of masking points outside the map
        self._padded_costmap = np.pad(self.costmap, 1, constant_values=UNKNOWN)

    # ------------------------------------------------------------------------------------------ loading
    @classmethod
    def load(
        cls,
        yaml_path: str | Path,
        inscribed_radius_m: float = 0.3,
        inflation_radius_m: float = 0.6,
        cost_scaling_per_m: float = 5.0,
    ) -> OccupancyMap:
        """Read a map_server YAML (image, resolution, origin, negate, occupied_thresh, free_thresh[, mode])."""
        path = Path(yaml_path)
        data = read_yaml(path)
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: expected a mapping")
        for key in ("image", "resolution", "origin"):
            if key not in data:
                raise ConfigError(f"{path}: missing key '{key}'")
        try:
            resolution = float(data["resolution"])
            origin = [float(v) for v in data["origin"]]
            negate = bool(int(data.get("negate", 0)))
            occupied_thresh = float(data.get("occupied_thresh", 0.65))
            free_thresh = float(data.get("free_thresh", 0.196))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{path}: bad number in the map description: {exc}") from exc
        if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
            raise ConfigError(f"{path}: 'origin' must be [x m, y m, yaw rad], got {data['origin']!r}")
        image_path = Path(str(data["image"]))
        if not image_path.is_absolute():
            image_path = path.parent / image_path
        occupancy = occupancy_from_image(
            _read_image(image_path), negate, occupied_thresh, free_thresh, str(data.get("mode", "trinary"))
        )
        return cls(
            occupancy,
            resolution,
            np.array(origin[:2]),
            origin[2],
            inscribed_radius_m,
            inflation_radius_m,
            cost_scaling_per_m,
            source=path,
        )

    # ------------------------------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple[int, int]:
        return self.occupancy.shape

    def world_to_cell(self, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, inside) of points (..., 2) in the map frame."""
        xy = np.asarray(xy_m, dtype=float)
        return self.cells_of(xy[..., 0], xy[..., 1])

    def cells_of(self, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, inside) of points given as separate x and y arrays (the IK's hot path: no stacking)."""
        dx, dy = np.asarray(x_m, dtype=float) - self.origin_xy_m[0], np.asarray(y_m, dtype=float) - self.origin_xy_m[1]
        if self.origin_yaw_rad:
            c, s = self._rotation[0, 0], self._rotation[1, 0]
            dx, dy = dx * c + dy * s, dy * c - dx * s  # rotate by -yaw
        with np.errstate(invalid="ignore"):
            cols = np.floor(dx / self.resolution_m)
            rows = np.floor(dy / self.resolution_m)
        inside = (rows >= 0) & (rows < self.shape[0]) & (cols >= 0) & (cols < self.shape[1])
        rows = np.where(inside, rows, 0).astype(np.intp)
        cols = np.where(inside, cols, 0).astype(np.intp)
        return rows, cols, inside

    def cell_to_world(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Cell centres (..., 2) in the map frame."""
        local = np.stack([(np.asarray(cols) + 0.5) * self.resolution_m, (np.asarray(rows) + 0.5) * self.resolution_m])
        return np.moveaxis(local, 0, -1) @ self._rotation.T + self.origin_xy_m

    def values_at(self, xy_m: np.ndarray, inflated: bool = True) -> np.ndarray:
        """Occupancy values (-1 unknown or outside the map) at points (..., 2)."""
        grid = self.costmap if inflated else self.occupancy
        rows, cols, inside = self.world_to_cell(xy_m)
        return np.where(inside, grid[rows, cols], UNKNOWN).astype(np.int8)

    def is_allowed(self, xy_m: np.ndarray, col_thresh: float) -> np.ndarray:
        """Whether the inflated occupancy at points (..., 2) lies within [0, col_thresh] (False for NaN points)."""
        values = self.values_at(xy_m)
        return (values >= 0) & (values <= col_thresh)

    def is_allowed_xy(self, x_m: np.ndarray, y_m: np.ndarray, col_thresh: float) -> np.ndarray:
        """:meth:`is_allowed` for finite x and y arrays, with as few array operations as possible (the IK rates
        every pan sample's base position with it)."""
        dx, dy = x_m - self.origin_xy_m[0], y_m - self.origin_xy_m[1]
        if self.origin_yaw_rad:
            c, s = self._rotation[0, 0], self._rotation[1, 0]
            dx, dy = dx * c + dy * s, dy * c - dx * s
        height, width = self.shape
        cols = np.clip(np.floor(dx / self.resolution_m), -1, width).astype(np.intp)
        rows = np.clip(np.floor(dy / self.resolution_m), -1, height).astype(np.intp)
        values = self._padded_costmap[rows + 1, cols + 1]
        return (values >= 0) & (values <= col_thresh)

    # ------------------------------------------------------------------------------------------ paths
    def planner(self, col_thresh: float) -> GridPlanner:
        """The (cached) shortest-path planner on the cells allowed under ``col_thresh``."""
        key = float(col_thresh)
        if key not in self._planners:
            self._planners[key] = GridPlanner(self, key)
        return self._planners[key]


def polyline_length(points: np.ndarray) -> float:
    points = np.asarray(points, dtype=float)
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else 0.0


class GridPlanner:
    """Shortest 8-connected paths over the allowed cells of an :class:`OccupancyMap` (scikit-image MCP).

    The search from a start cell is cached, so rating many goals from one robot position (the IK's NAVIGATION_PATH
    heuristic) costs one search plus one traceback per goal. Thread-safe (rospy serves requests in threads).
    """

    def __init__(self, grid: OccupancyMap, col_thresh: float):
        from skimage.graph import MCP_Geometric

        self.grid = grid
        self.col_thresh = col_thresh
        self.traversable = (grid.costmap >= 0) & (grid.costmap <= col_thresh)
        self._mcp = MCP_Geometric(np.where(self.traversable, 1.0, np.inf), fully_connected=True)
        self._cumulative: np.ndarray | None = None
        self._searched_from: tuple[int, int] | None = None
        self._lock = threading.Lock()

    def snap(self, xy_m: np.ndarray, tolerance_m: float = 0.0) -> tuple[int, int] | None:
        """The traversable cell of a point, else the nearest traversable cell within ``tolerance_m``, else None."""
        rows, cols, inside = self.grid.world_to_cell(np.asarray(xy_m, dtype=float)[None, :2])
        if inside[0] and self.traversable[rows[0], cols[0]]:
            return int(rows[0]), int(cols[0])
        reach = math.ceil(tolerance_m / self.grid.resolution_m)
        if reach <= 0:
            return None
        r = np.arange(-reach, reach + 1)
        dr, dc = np.meshgrid(r, r, indexing="ij")
        cand_r, cand_c = rows[0] + dr.ravel(), cols[0] + dc.ravel()
        ok = (cand_r >= 0) & (cand_r < self.grid.shape[0]) & (cand_c >= 0) & (cand_c < self.grid.shape[1])
        cand_r, cand_c = cand_r[ok], cand_c[ok]
        centres = self.grid.cell_to_world(cand_r, cand_c)
        distance = np.linalg.norm(centres - np.asarray(xy_m, dtype=float)[:2], axis=1)
        usable = self.traversable[cand_r, cand_c] & (distance <= tolerance_m)
        if not usable.any():
            return None
        best = np.flatnonzero(usable)[np.argmin(distance[usable])]
        return int(cand_r[best]), int(cand_c[best])

    def _search_from(self, start: tuple[int, int]) -> None:
        if self._searched_from != start:
            self._cumulative, _ = self._mcp.find_costs([start])
            self._searched_from = start

    def line_is_clear(self, a_xy: np.ndarray, b_xy: np.ndarray) -> bool:
        """Whether the straight segment a -> b runs on traversable cells only (sampled every quarter cell)."""
        length = float(np.hypot(*(b_xy - a_xy)))
        count = max(2, math.ceil(length / (0.25 * self.grid.resolution_m)) + 1)
        t = np.linspace(0.0, 1.0, count)[:, None]
        rows, cols, inside = self.grid.world_to_cell(a_xy + t * (b_xy - a_xy))
        return bool(np.all(inside & self.traversable[rows, cols]))

    def _farthest_visible(self, points: np.ndarray, i: int) -> int:
        """A later index j as far as possible with a clear segment i -> j (galloping, then bisecting): the next
        point of the straightened path. Cells next to each other are always connected (the search's own step)."""
        last = len(points) - 1
        if i + 1 == last or self.line_is_clear(points[i], points[last]):
            return last
        clear, step = i + 1, 2
        while i + step < last and self.line_is_clear(points[i], points[i + step]):
            clear, step = i + step, 2 * step
        blocked = min(i + step, last)
        while blocked - clear > 1:
            middle = (clear + blocked) // 2
            if self.line_is_clear(points[i], points[middle]):
                clear = middle
            else:
                blocked = middle
        return clear

    def _polyline(self, cells: list, start_xy: np.ndarray, goal_xy: np.ndarray) -> np.ndarray:
        cells = np.asarray(cells, dtype=np.intp).reshape(-1, 2)
        middle = self.grid.cell_to_world(cells[1:-1, 0], cells[1:-1, 1]).reshape(-1, 2)
        points = np.vstack([start_xy[None, :2], middle, goal_xy[None, :2]])
        kept, i = [0], 0
        while i < len(points) - 1:
            i = self._farthest_visible(points, i)
            kept.append(i)
        return points[kept]

    def plan(self, start_xy_m, goal_xy_m, tolerance_m: float = 0.0) -> np.ndarray | None:
        """Polyline (k, 2) from start to goal in metres, or None when either end is blocked or no path exists."""
        paths = self.plan_many(start_xy_m, np.asarray(goal_xy_m, dtype=float)[None, :2], tolerance_m)
        return paths[0]

    def plan_many(self, start_xy_m, goals_xy_m, tolerance_m: float = 0.0) -> list[np.ndarray | None]:
        """Polylines from one start to each of ``goals_xy_m`` (k, 2); None where blocked or unreachable."""
        start_xy = np.asarray(start_xy_m, dtype=float)[:2]
        goals = np.asarray(goals_xy_m, dtype=float).reshape(-1, 2)
        start = self.snap(start_xy, tolerance_m)
        if start is None:
            return [None] * len(goals)
        out: list[np.ndarray | None] = []
        with self._lock:
            self._search_from(start)
            for goal_xy in goals:
                goal = self.snap(goal_xy, tolerance_m)
                if goal is None or not np.isfinite(self._cumulative[goal]):
                    out.append(None)
                    continue
                cells = self._mcp.traceback(goal)
                out.append(self._polyline(cells, start_xy, goal_xy))
        return out
