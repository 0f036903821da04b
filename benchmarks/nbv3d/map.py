"""Speed of the 3D NBV map core (nbv/voxel_map.py, nbv/gains.py, nbv/meshing.py) on real simulated PhoXi frames.

Scene: a torus (major radius 60 mm, minor 25 mm) standing on a box on a table, rendered by the ROS-free PhoXi
simulation (model S, low resolution 1032 x 772, noise on) from 0.45 m at 45 deg elevation. Measured (median of
--repeats warm runs; the numba JIT/cache load is timed separately as the first call):

(a) fusing that frame into a 2 mm and a 5 mm grid over a 0.3 m cube ROI (and, for reference, a synthetic 100 k
    point sphere frame at ~0.45 m);
(b) evaluating --views candidate poses on the 5 mm planning grid (and the 2 mm grid) with a 64 x 48 bundle;
(c) labels, growth / candidate voxels, predicted surface, the planning grid;
(d) the TSDF at 2 mm: integrating the frame and extracting the mesh.

    python -m benchmarks.nbv3d.map                       # prints the figures
    python -m benchmarks.nbv3d.map --views 150 --json bench.json
    python -m benchmarks.nbv3d.map --cold                # also: a fresh numba cache in a child process (cold JIT)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time

import numba
import numpy as np
import trimesh

from agiprobot_measurement.common.geometry import look_at
from agiprobot_measurement.nbv.volumetric.gains import ViewModel, evaluate_views
from agiprobot_measurement.nbv.volumetric.meshing import TSDFVolume
from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_LOW, load_scanner_model
from agiprobot_measurement.sensors.phoxi.renderer import ScanSettings, StructuredLightScanner
from agiprobot_measurement.sensors.phoxi.scene_geometry import SceneGeometry
from benchmarks.harness import ChildFailed, load_conditions, run_process, timed, write_json

#: the cold-JIT child: imports, a first fusion, pooling and gains with an empty numba cache (seconds of each)
COLD_JIT_CODE = (
    "import time, numpy as np; t=time.perf_counter();"
    "from agiprobot_measurement.nbv.volumetric.voxel_map import VoxelMap, MapConfig;"
    "from agiprobot_measurement.nbv.volumetric.gains import ViewModel, evaluate_views;"
    "from agiprobot_measurement.common.geometry import look_at;"
    "g=VoxelMap([0,0,0],[0.05]*3, MapConfig(resolution_m=0.005)); t1=time.perf_counter();"
    "g.integrate([0.025,0.025,0.5], np.array([[0.025,0.025,0.025]])); t2=time.perf_counter();"
    "g.coarse().predicted_surface(g.growth_voxels()); t3=time.perf_counter();"
    "v=ViewModel(0.7,0.5,0.3,0.6,np.zeros(3)); evaluate_views(g,look_at([0.025,0.025,0.5],[0.025]*3,up=(0,1,0))[None],v);"
    "t4=time.perf_counter(); print(t1-t, t2-t1, t3-t2, t4-t3)"
)

DEFAULTS = load_conditions("nbv3d_map").mapping("defaults")


def scene_frame():
    table = trimesh.creation.box(extents=[1.0, 1.0, 0.04])
    table.apply_translation([0, 0, -0.02])
    pedestal = trimesh.creation.box(extents=[0.08, 0.08, 0.04])
    pedestal.apply_translation([0, 0, 0.02])
    torus = trimesh.creation.torus(major_radius=0.06, minor_radius=0.025)
    torus.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))
    torus.apply_translation([0, 0, 0.04 + 0.085])
    geometry = SceneGeometry.concatenate(
        [SceneGeometry.from_trimesh(m, n, 0.6) for m, n in ((table, "table"), (pedestal, "pedestal"), (torus, "part"))]
    )
    centre = np.array([0.0, 0.0, 0.12])
    eye = centre + 0.45 * np.array([math.cos(math.radians(45)), 0.0, math.sin(math.radians(45))])
    pose = look_at(eye, centre)
    model = load_scanner_model("S")
    scanner = StructuredLightScanner(model, workers=2)
    frame = scanner.capture(geometry, pose, ScanSettings(resolution=RESOLUTION_LOW, noise=True, seed=1))
    valid = frame.valid.reshape(-1)
    cam_points = frame.points_m().reshape(-1, 3)[valid]
    points = cam_points @ pose[:3, :3].T + pose[:3, 3]
    normals = frame.normals.reshape(-1, 3)[valid] @ pose[:3, :3].T
    sigma = frame.confidence.reshape(-1)[valid]
    static = trimesh.util.concatenate([table, pedestal])
    return model, frame, pose, points, normals, sigma, centre, static


def sphere_frame(n=100_000, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((3 * n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centre = np.array([0.0, 0.0, 0.12])
    sensor = centre + 0.45 * np.array([math.cos(math.radians(45)), 0.0, math.sin(math.radians(45))])
    pts = centre + 0.1 * d
    seen = np.einsum("ij,ij->i", d, sensor - pts) > 0
    return sensor, pts[seen][:n], d[seen][:n]


CPU_TIMES: dict = {}


def timed_figures(fn, repeats, key=None):
    """(median, min, max) wall seconds over ``repeats`` calls and the last result; the median CPU seconds of the
    process (all threads) go to CPU_TIMES[key]: on a shared machine wall time includes waiting for a core."""
    timing = timed(fn, repeats)
    if key:
        CPU_TIMES[key] = float(timing.cpu_median_s)
    return float(timing.median_s), float(timing.min_s), float(timing.max_s), timing.result


def candidate_poses(centre, n, distance, seed=0):
    rng = np.random.default_rng(seed)
    poses = []
    while len(poses) < n:
        u = rng.standard_normal(3)
        u /= np.linalg.norm(u)
        if u[2] < 0.1:
            continue
        poses.append(look_at(centre + distance * u, centre, up=(0, 0, 1) if abs(u[2]) < 0.99 else (1, 0, 0)))
    return np.array(poses)


def run(args) -> dict:
    results: dict = {}
    t0 = time.perf_counter()
    model, frame, pose, points, normals, sigma, centre, static = scene_frame()
    results["render_s"] = time.perf_counter() - t0
    results["frame_valid_points"] = len(points)
    results["frame_pixels"] = frame.width * frame.height
    sensor = pose[:3, 3]
    roi_min = centre - 0.15
    roi_max = centre + 0.15
    fuse = {}
    for res in (0.002, 0.005):
        config = MapConfig(resolution_m=res, planning_resolution_m=max(res, 0.005))
        first = VoxelMap(roi_min, roi_max, config)
        start = time.perf_counter()
        first.integrate(sensor, points, normals, sigma)
        cold = time.perf_counter() - start

        def one(res=res, config=config):
            grid = VoxelMap(roi_min, roi_max, config)
            stats = grid.integrate(sensor, points, normals, sigma)
            return stats

        med, lo, hi, stats = timed_figures(one, args.repeats, f"fuse_phoxi_{res * 1000:g}mm")
        s_sensor, s_pts, s_nrm = sphere_frame()

        def sphere(res=res, config=config, s_sensor=s_sensor, s_pts=s_pts, s_nrm=s_nrm):
            grid = VoxelMap(roi_min, roi_max, config)
            return grid.integrate(s_sensor, s_pts, s_nrm)

        s_med, s_lo, s_hi, s_stats = timed_figures(sphere, args.repeats, f"fuse_sphere_{res * 1000:g}mm")
        fuse[f"{res * 1000:g}mm"] = {
            "shape": list(first.shape),
            "phoxi_frame": {
                "points": stats["points"],
                "free_updates": stats["free_updates"],
                "hit_updates": stats["hit_updates"],
                "integrate_s": stats["seconds"],
                "median_s": med,
                "min_s": lo,
                "max_s": hi,
                "first_call_s": cold,
            },
            "sphere_100k": {
                "free_updates": s_stats["free_updates"],
                "hit_updates": s_stats["hit_updates"],
                "median_s": s_med,
                "min_s": s_lo,
                "max_s": s_hi,
            },
        }
    results["fuse"] = fuse

    grid = VoxelMap(roi_min, roi_max, MapConfig(resolution_m=0.002, planning_resolution_m=0.005))
    start = time.perf_counter()
    grid.set_static(static)
    results["set_static_s"] = time.perf_counter() - start
    stats = grid.integrate(sensor, points, normals, sigma)
    results["fuse_with_static"] = {k: stats[k] for k in ("points_kept", "points_static", "points_outside")}

    def labels():
        grid.invalidate()
        coarse = grid.coarse()
        growth = coarse.growth_voxels()
        cand = coarse.candidate_voxels()
        coarse.predicted_surface(growth)
        fine_growth = grid.growth_voxels()
        return len(growth), len(cand), len(fine_growth)

    timed_figures(labels, 1)
    med, lo, hi, counts = timed_figures(labels, args.repeats, "labels")
    results["labels_coarse_growth_candidates_predicted_s"] = {
        "median_s": med,
        "min_s": lo,
        "max_s": hi,
        "coarse_growth": counts[0],
        "coarse_candidates": counts[1],
        "fine_growth": counts[2],
    }

    with tempfile.TemporaryDirectory() as out:
        exports = {}
        for name, fn in (
            ("save_npz_s", lambda: grid.save_npz(os.path.join(out, "map.npz"))),
            ("save_bt_s", lambda: grid.save_bt(os.path.join(out, "map.bt"))),
            ("export_cloud_ply_1mm_s", lambda: grid.export_cloud_ply(os.path.join(out, "cloud.ply"))),
        ):
            start = time.perf_counter()
            value = fn()
            exports[name] = time.perf_counter() - start
            if name.startswith("export"):
                exports["cloud_points"] = int(value)
        results["exports_2mm_one_frame"] = exports

    view = ViewModel.from_scanner_model(model, rays_h=64, rays_v=48)
    poses = candidate_poses(centre, args.views, model.sweet_spot_mm / 1000.0)
    gains = {}
    for name, target in (("5mm", grid.coarse()), ("2mm", grid)):
        start = time.perf_counter()
        evaluate_views(target, poses[:2], view)
        cold = time.perf_counter() - start
        n = args.views if name == "5mm" else min(args.views, 30)

        def evaluate(target=target, n=n):
            return evaluate_views(target, poses[:n], view)

        med, lo, hi, out = timed_figures(evaluate, args.repeats, f"gains_{name}")
        gains[name] = {
            "views": n,
            "median_s": med,
            "ms_per_view": 1000 * med / n,
            "min_s": lo,
            "max_s": hi,
            "cpu_ms_per_view": 1000 * CPU_TIMES[f"gains_{name}"] / n,
            "first_call_s": cold,
            "mean_visible_voxels": float(out.visible_voxels.mean()),
        }
    results["gains_64x48"] = gains

    tsdf_times = {}
    volume = TSDFVolume(roi_min, roi_max, voxel_m=0.002, truncation_m=0.006)
    depth = frame.depth_mm / 1000.0
    start = time.perf_counter()
    volume.integrate(depth, frame.intrinsics, pose)
    tsdf_times["first_call_s"] = time.perf_counter() - start
    med, lo, hi, _ = timed_figures(
        lambda: volume.integrate(depth, frame.intrinsics, pose), args.repeats, "tsdf_integrate"
    )
    tsdf_times.update({"integrate_median_s": med, "integrate_min_s": lo})
    med, lo, hi, mesh = timed_figures(volume.mesh, max(1, args.repeats // 2), "tsdf_mesh")
    tsdf_times.update({"mesh_median_s": med, "faces": len(mesh.faces)})
    results["tsdf_2mm"] = tsdf_times
    results["numba_threads"] = int(numba.get_num_threads())
    results["cpu_s_median"] = dict(CPU_TIMES)
    results["load_average_1min"] = os.getloadavg()[0]
    return results


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--views", type=int, default=DEFAULTS["views"], help="candidate poses evaluated at 5 mm (%(default)s)"
    )
    parser.add_argument(
        "--repeats", type=int, default=DEFAULTS["repeats"], help="warm repetitions per measurement (median)"
    )
    parser.add_argument("--json", help="write the figures to this JSON file")
    parser.add_argument("--cold", action="store_true", help="also time the first calls with an empty numba cache")
    args = parser.parse_args(argv)
    if args.views < 2 or args.repeats < 1:
        parser.error("--views must be >= 2 and --repeats >= 1")
    results = run(args)
    if args.cold:
        with tempfile.TemporaryDirectory() as cache:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache)
            done = run_process([sys.executable, "-c", COLD_JIT_CODE], env=env)
            if done.returncode != 0:
                raise ChildFailed(f"cold JIT child: exit {done.returncode}: {done.stderr.strip()[-500:]}")
            imp, fuse, pooling, gains = (float(v) for v in done.stdout.split())
            results["cold_jit_s"] = {
                "import": imp,
                "fuse": fuse,
                "coarse_and_predicted_surface": pooling,
                "evaluate_views": gains,
            }
    print(json.dumps(results, indent=2))
    if args.json:
        write_json(args.json, results, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
