"""TSDF integration and meshing: evfuse's numba kernel against Open3D's, on the same views.

The views are exact depth maps of an analytic table top (a 1.2 m square floor, a box and a ball
on it) from ``--views`` cameras on a ring around it, 240x180 pixels (DAVIS240C-sized, pinhole:
Open3D's integration takes no distortion), ray-cast in closed form, so both meshes are scored
against the exact surface:

* accuracy: each mesh vertex's distance to the analytic surface (mean, 99th percentile, max, in
  millimetres and voxels);
* completeness: the share of the views' exact points (their depth back-projected) within one
  voxel of the mesh (the mesh sampled every voxel / 4).

Every volume gets the same voxel size and truncation (:func:`fusion.globalmap.tsdf.tsdf_grid`'s
defaults from the data): evfuse's :class:`~fusion.globalmap.tsdf.TSDFVolume` on that box
(``evfuse``) and on the cube Open3D's uniform volume needs (``evfuse-cube``, the same grid
points), Open3D's legacy ``UniformTSDFVolume`` (voxel centres at ``origin + (i + 0.5) voxel``,
placed on evfuse's grid points) and its hashed ``t.geometry.VoxelBlockGrid`` (16^3 blocks near
the surface only; its legacy ``ScalableTSDFVolume`` returned empty meshes in Open3D 0.20).
Each runs in its own child process, ``--rounds`` children of each in turn: integration
time of all views (best of ``--repeats`` in a child and of the rounds, after one warm-up that
holds numba's compilation, reported apart), marching-cubes time, peak memory (tracemalloc:
Python's and NumPy's allocations; the child's ru_maxrss above what it held before the volume,
which sees C++ allocations too but only the pages written), and the install size of what each
needs beyond NumPy (``du`` of the packages' folders; numba and scikit-image are evfuse
dependencies already, so evfuse's TSDF installs nothing new).

Open3D is not a dependency of evfuse: install it in a separate environment
(``python3.11 -m venv /tmp/o3d && /tmp/o3d/bin/pip install open3d numpy``; on Debian its wheel
also needs ``libusb-1.0-0``) and pass that interpreter as ``--open3d /tmp/o3d/bin/python``;
without it the table says Open3D was skipped.

Printed and written to ``benchmarks/results/tsdf.json``.
Run: ``.venv/bin/python benchmarks/bench_tsdf.py [--views 16] [--open3d PYTHON]``.

This file's top level imports only the standard library and NumPy: Open3D's child runs it with
Open3D's interpreter (``--worker open3d-uniform IN OUT``), where evfuse is not installed.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

FLOOR_HALF = 0.6                                    # the floor: |x|, |y| <= 0.6, z = 0
BOX = (np.array([-0.3, -0.25, 0.0]), np.array([0.0, 0.05, 0.22]))   # (lo, hi)
BALL = (np.array([0.22, 0.12, 0.13]), 0.13)         # (centre, radius), resting on the floor
SIZE, FOCAL = (240, 180), 200.0


# --- the analytic scene -------------------------------------------------------------------

def ring_poses(count: int) -> list[np.ndarray]:
    """``count`` poses on a ring of radius 1.0 m, 0.55-0.85 m above the floor, looking at a
    point 5 cm above the floor's centre."""
    from sim.se3 import look_at, make_pose

    poses = []
    for i in range(count):
        angle = 2 * np.pi * i / count
        height = 0.7 + 0.15 * np.sin(3 * angle)
        eye = (np.cos(angle), np.sin(angle), height)
        poses.append(make_pose(look_at(eye, (0.0, 0.0, 0.05)), eye))
    return poses


def scene_depth(rays_camera: np.ndarray, T: np.ndarray) -> np.ndarray:
    """z-depth of the first hit of each ray (0: none).

    Parameters
    ----------
    rays_camera : (N, 3) float64 ndarray, camera frame, each with z = 1
    T : (4, 4) camera-to-world pose

    Returns
    -------
    (N,) float64 ndarray, metres (the ray parameter, since the rays have z = 1)
    """
    d = rays_camera @ T[:3, :3].T
    o = T[:3, 3]
    best = np.full(len(d), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[:, 2]                                             # floor
        p = o + t[:, None] * d
        hit = (t > 0) & (np.abs(p[:, 0]) <= FLOOR_HALF) & (np.abs(p[:, 1]) <= FLOOR_HALF)
        best = np.where(hit, t, best)
        t1, t2 = (BOX[0] - o) / d, (BOX[1] - o) / d                     # box
        near = np.nanmax(np.minimum(t1, t2), 1)
        far = np.nanmin(np.maximum(t1, t2), 1)
        best = np.where((near <= far) & (near > 0) & (near < best), near, best)
        oc = o - BALL[0]                                                # ball
        a, b, c = np.sum(d * d, 1), 2 * d @ oc, oc @ oc - BALL[1] ** 2
        disc = b * b - 4 * a * c
        t = (-b - np.sqrt(disc)) / (2 * a)
        best = np.where((disc > 0) & (t > 0) & (t < best), t, best)
    return np.where(np.isfinite(best), best, 0.0)


def surface_distance(points: np.ndarray) -> np.ndarray:
    """Distance of points to the scene's surface, metres: the nearest of the floor square, the
    box's faces and the ball's sphere (the parts hidden where they touch count too, which can
    only make a mesh look closer than it is, by nothing where the mesh has no vertex there)."""
    p = np.asarray(points, float)
    outside = np.maximum(np.abs(p[:, :2]) - FLOOR_HALF, 0.0)
    floor = np.sqrt(np.sum(outside**2, 1) + p[:, 2] ** 2)
    centre, half = (BOX[0] + BOX[1]) / 2, (BOX[1] - BOX[0]) / 2
    q = np.abs(p - centre) - half
    box = np.abs(np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(1), 0.0))
    ball = np.abs(np.linalg.norm(p - BALL[0], axis=1) - BALL[1])
    return np.minimum(np.minimum(floor, box), ball)


def make_views(count: int):
    """The benchmark's exact depth views (list of DepthView) of a pinhole 240x180 camera."""
    from fusion.globalmap.views import DepthView
    from sim.camera import Camera

    camera = Camera(SIZE[0], SIZE[1], FOCAL, FOCAL, (SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2)
    xy = camera.normalized_pixel_centres().reshape(-1, 2)
    rays = np.concatenate([xy, np.ones((len(xy), 1))], 1)
    return [DepthView(scene_depth(rays, T).reshape(SIZE[1], SIZE[0]).astype(np.float32),
                      camera, T, t=float(i), name=f"view {i}")
            for i, T in enumerate(ring_poses(count))]


# --- the children ---------------------------------------------------------------------------

def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _worker_evfuse(data: dict, repeats: int, cube: bool) -> dict:
    from fusion.globalmap.tsdf import TSDFVolume
    from fusion.globalmap.views import DepthView
    from sim.camera import Camera

    fx, fy, cx, cy = data["intrinsics"]
    camera = Camera(int(data["depth"].shape[2]), int(data["depth"].shape[1]), fx, fy, cx, cy)
    views = [DepthView(d, camera, T) for d, T in zip(data["depth"], data["poses"], strict=True)]
    lo, voxel, trunc = data["lo"], float(data["voxel"]), float(data["truncation"])
    shape = np.full(3, data["shape"].max()) if cube else data["shape"]
    hi = lo + (shape - 1) * voxel
    start = time.perf_counter()
    warm = TSDFVolume(lo, lo + 2 * voxel, voxel, trunc)
    warm.integrate(views[0])
    warm.mesh()
    compile_s = time.perf_counter() - start
    rss_before = _maxrss_mb()
    times = []
    tracemalloc.start()
    volume = None
    for _ in range(repeats):
        volume = None  # one volume at a time
        volume = TSDFVolume(lo, hi, voxel, trunc)
        start = time.perf_counter()
        for view in views:
            volume.integrate(view)
        times.append(time.perf_counter() - start)
    start = time.perf_counter()
    mesh = volume.mesh()
    mesh_s = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"integrate_s": min(times), "mesh_s": mesh_s, "compile_s": compile_s,
            "tracemalloc_peak_mb": peak / 2**20, "maxrss_increase_mb": _maxrss_mb() - rss_before,
            "threads": int(__import__("numba").get_num_threads()),
            "voxels": int(np.prod(volume.shape)),
            "vertices": mesh.vertices, "faces": mesh.faces}


def _worker_open3d(data: dict, repeats: int, kind: str) -> dict:
    import open3d as o3d

    integration = o3d.pipelines.integration
    height, width = data["depth"].shape[1:]
    fx, fy, cx, cy = data["intrinsics"]
    intrinsic = o3d.camera.PinholeCameraIntrinsic(int(width), int(height), fx, fy, cx, cy)
    voxel, trunc = float(data["voxel"]), float(data["truncation"])
    side = int(data["shape"].max())
    images = []
    for depth in data["depth"]:
        colour = o3d.geometry.Image(np.zeros((height, width, 3), np.uint8))
        images.append(o3d.geometry.RGBDImage.create_from_color_and_depth(
            colour, o3d.geometry.Image(np.ascontiguousarray(depth)), depth_scale=1.0,
            depth_trunc=1e6, convert_rgb_to_intensity=False))
    extrinsics = [np.linalg.inv(T) for T in data["poses"]]

    rss_before = _maxrss_mb()
    times = []
    tracemalloc.start()
    if kind == "uniform":
        volume = None
        for _ in range(repeats):
            volume = None  # one volume at a time
            volume = integration.UniformTSDFVolume(
                length=side * voxel, resolution=side, sdf_trunc=trunc,
                color_type=integration.TSDFVolumeColorType.NoColor,
                origin=np.asarray(data["lo"], float).reshape(3, 1) - voxel / 2)
            start = time.perf_counter()
            for image, extrinsic in zip(images, extrinsics, strict=True):
                volume.integrate(image, intrinsic, extrinsic)
            times.append(time.perf_counter() - start)
        start = time.perf_counter()
        mesh = volume.extract_triangle_mesh()
        mesh_s = time.perf_counter() - start
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    else:
        vertices, faces, times, mesh_s = _block_grid(data, repeats, voxel, trunc)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"integrate_s": min(times), "mesh_s": mesh_s, "compile_s": 0.0,
            "tracemalloc_peak_mb": peak / 2**20, "maxrss_increase_mb": _maxrss_mb() - rss_before,
            "threads": os.cpu_count(), "voxels": side**3 if kind == "uniform" else None,
            "vertices": vertices, "faces": faces}


def _block_grid(data: dict, repeats: int, voxel: float, trunc: float):
    """Open3D's hashed TSDF (``t.geometry.VoxelBlockGrid``, 16^3 blocks allocated near the
    surface). Its legacy ``ScalableTSDFVolume`` returned empty meshes in Open3D 0.20 here (a
    plane in front of the camera too), and 0.20's block grid extracts a mesh only with a colour
    attribute: it carries a zero colour (3 float32 a voxel), as Open3D's own examples do.
    ``weight_threshold=0.5``: a voxel observed once counts, as in evfuse's mesh."""
    import open3d as o3d
    import open3d.core as o3c

    height, width = data["depth"].shape[1:]
    fx, fy, cx, cy = data["intrinsics"]
    K = o3c.Tensor(np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), o3c.float64)
    depths = [o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(d))) for d in data["depth"]]
    colour = o3d.t.geometry.Image(o3c.Tensor(np.zeros((height, width, 3), np.float32)))
    extrinsics = [o3c.Tensor(np.linalg.inv(T), o3c.float64) for T in data["poses"]]
    blocks = int(np.prod(np.ceil(data["shape"] / 16.0) + 1)) * 2
    multiplier = trunc / voxel
    times, grid = [], None
    for _ in range(repeats):
        grid = None  # one volume at a time
        grid = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32), attr_channels=(1, 1, 3),
            voxel_size=voxel, block_resolution=16, block_count=blocks,
            device=o3c.Device("CPU:0"))
        start = time.perf_counter()
        for depth, extrinsic in zip(depths, extrinsics, strict=True):
            touched = grid.compute_unique_block_coordinates(
                depth, K, extrinsic, 1.0, 1e3, trunc_voxel_multiplier=multiplier)
            grid.integrate(touched, depth, colour, K, extrinsic, 1.0, 1e3,
                           trunc_voxel_multiplier=multiplier)
        times.append(time.perf_counter() - start)
    start = time.perf_counter()
    mesh = grid.extract_triangle_mesh(weight_threshold=0.5)
    mesh_s = time.perf_counter() - start
    return (mesh.vertex.positions.numpy().astype(np.float64),
            mesh.triangle.indices.numpy().astype(np.int64), times, mesh_s)


def _worker(kind: str, source: str, target: str, repeats: int) -> None:
    data = dict(np.load(source))
    if kind.startswith("evfuse"):
        result = _worker_evfuse(data, repeats, cube=kind == "evfuse-cube")
    else:
        result = _worker_open3d(data, repeats, kind.removeprefix("open3d-"))
    np.savez(target, **{k: np.asarray(v if v is not None else np.nan)
                        for k, v in result.items()})


def run_child(python: str, kind: str, source: Path, repeats: int) -> dict:
    """Run one implementation in a child process; its figures and mesh."""
    target = source.with_name(f"{kind}.npz")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    subprocess.run([python, str(Path(__file__).resolve()), "--worker", kind, str(source),
                    str(target), "--repeats", str(repeats)], check=True, env=env)
    with np.load(target) as data:
        return {k: data[k] if data[k].ndim else data[k].item() for k in data.files}


# --- scoring and the table ------------------------------------------------------------------

def score(result: dict, views, voxel: float) -> dict:
    """Accuracy and completeness of a child's mesh against the exact scene."""
    from scipy.spatial import cKDTree

    from fusion.globalmap.tsdf import Mesh

    mesh = Mesh(result["vertices"], result["faces"])
    error = surface_distance(mesh.vertices) if len(mesh.vertices) else np.array([np.nan])
    truth = np.concatenate([view.points_world() for view in views])
    samples = mesh.sample(voxel / 4)
    gap = cKDTree(samples).query(truth)[0] if len(samples) else np.full(len(truth), np.inf)
    return {"vertices": len(mesh.vertices), "faces": len(mesh.faces),
            "accuracy_mean_mm": 1e3 * float(np.mean(error)),
            "accuracy_p99_mm": 1e3 * float(np.percentile(error, 99)),
            "accuracy_max_mm": 1e3 * float(np.max(error)),
            "accuracy_max_voxels": float(np.max(error) / voxel),
            "vertices_within_half_voxel": float(np.mean(error <= voxel / 2)),
            "completeness_within_voxel": float(np.mean(gap <= voxel)),
            "completeness_mean_mm": 1e3 * float(np.mean(gap))}


def install_mb(python: str, packages: list[str]) -> float:
    """Disk size of the named packages' folders in ``python``'s environment, MB (``du``)."""
    code = ("import importlib.util as u, os, sys\n"
            "for name in sys.argv[1:]:\n"
            "    spec = u.find_spec(name)\n"
            "    print(os.path.dirname(spec.origin) if spec and spec.origin else '')\n")
    folders = subprocess.run([python, "-c", code, *packages], check=True, text=True,
                             capture_output=True).stdout.split()
    sizes = subprocess.run(["du", "-sk", *folders], check=True, text=True,
                           capture_output=True).stdout.split()[::2]
    return sum(int(s) for s in sizes) / 1024.0


def main(argv: list[str] | None = None) -> dict | None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3,
                        help="integrations of all views in one child (its best is kept)")
    parser.add_argument("--rounds", type=int, default=3,
                        help="children per implementation, run in turn (the best is kept)")
    parser.add_argument("--voxel", type=float,
                        help="voxel size, metres (default: the data's rule)")
    parser.add_argument("--open3d", metavar="PYTHON",
                        help="interpreter of an environment with open3d (skipped without)")
    parser.add_argument("--worker", nargs=3, metavar=("KIND", "IN", "OUT"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        _worker(*args.worker, repeats=args.repeats)
        return None

    from fusion.globalmap.tsdf import TSDFVolume, tsdf_grid

    views = make_views(args.views)
    from fusion.globalmap.tsdf import TSDFParams

    lo, hi, voxel, truncation = tsdf_grid(views, TSDFParams(voxel_size=args.voxel))
    shape = np.asarray(TSDFVolume(lo, hi, voxel, truncation).shape)
    camera = views[0].camera
    report = {"views": len(views), "size": list(SIZE), "voxel_m": voxel,
              "truncation_m": truncation, "grid": shape.tolist(), "repeats": args.repeats,
              "rounds": args.rounds,
              "machine": f"{os.cpu_count()} cores, shared (loaded): compare within this run",
              "results": {}}
    print(f"{len(views)} exact views at {SIZE[0]}x{SIZE[1]}; voxel {voxel * 1e3:.2f} mm, "
          f"truncation {truncation * 1e3:.2f} mm, grid {' x '.join(map(str, shape))}")
    with tempfile.TemporaryDirectory(prefix="bench_tsdf_") as folder:
        source = Path(folder) / "views.npz"
        np.savez(source, depth=np.stack([v.depth for v in views]),
                 poses=np.stack([v.T_world_cam for v in views]),
                 intrinsics=np.array([camera.fx, camera.fy, camera.cx, camera.cy]),
                 lo=lo, voxel=voxel, truncation=truncation, shape=shape)
        ours = ["numba", "llvmlite", "skimage"]
        runs = [("evfuse", sys.executable, ours), ("evfuse-cube", sys.executable, ours)]
        if args.open3d:
            runs += [(kind, args.open3d, ["open3d"])
                     for kind in ("open3d-uniform", "open3d-blockgrid")]
        best: dict[str, dict] = {}
        for _ in range(args.rounds):   # in turn, so that the machine's load falls on all
            for kind, python, _ in runs:
                result = run_child(python, kind, source, args.repeats)
                if kind in best:
                    for key in ("integrate_s", "mesh_s"):
                        result[key] = min(result[key], best[kind][key])
                best[kind] = result
        for kind, python, packages in runs:
            result = best[kind]
            entry = {k: result[k] for k in ("integrate_s", "mesh_s", "compile_s",
                                           "tracemalloc_peak_mb", "maxrss_increase_mb",
                                           "threads", "voxels")}
            entry["install_mb"] = install_mb(python, packages)
            entry["install_packages"] = packages
            entry.update(score(result, views, voxel))
            report["results"][kind] = entry
    if not args.open3d:
        report["open3d"] = "skipped: no --open3d PYTHON given"
    rows = [("integrate all views (s)", "integrate_s", "{:.3f}"),
            ("per view (ms)", None, "{:.1f}"),
            ("marching cubes (s)", "mesh_s", "{:.3f}"),
            ("numba compile, once (s)", "compile_s", "{:.2f}"),
            ("tracemalloc peak (MB)", "tracemalloc_peak_mb", "{:.1f}"),
            ("ru_maxrss increase (MB)", "maxrss_increase_mb", "{:.1f}"),
            ("install beyond NumPy (MB)", "install_mb", "{:.0f}"),
            ("mesh vertices", "vertices", "{:d}"),
            ("accuracy mean (mm)", "accuracy_mean_mm", "{:.2f}"),
            ("accuracy p99 (mm)", "accuracy_p99_mm", "{:.2f}"),
            ("accuracy max (voxels)", "accuracy_max_voxels", "{:.2f}"),
            ("vertices within voxel/2", "vertices_within_half_voxel", "{:.1%}"),
            ("exact points within 1 voxel", "completeness_within_voxel", "{:.1%}")]
    kinds = list(report["results"])
    print(f"| {'':30s} | " + " | ".join(f"{k:>16s}" for k in kinds) + " |")
    for label, key, fmt in rows:
        cells = []
        for kind in kinds:
            entry = report["results"][kind]
            value = 1e3 * entry["integrate_s"] / len(views) if key is None else entry[key]
            cells.append(fmt.format(value))
        print(f"| {label:30s} | " + " | ".join(f"{c:>16s}" for c in cells) + " |")
    if "open3d-uniform" in report["results"]:
        results = report["results"]
        for ours, theirs in (("evfuse", "open3d-blockgrid"), ("evfuse-cube", "open3d-uniform")):
            ratio = results[ours]["integrate_s"] / results[theirs]["integrate_s"]
            report[f"{ours}_over_{theirs}_integrate"] = ratio
            print(f"integration time {ours} / {theirs}: {ratio:.2f}")
    else:
        print("Open3D: skipped (no --open3d PYTHON given)")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "tsdf.json").write_text(json.dumps(report, indent=2))
    print(f"written to {RESULTS / 'tsdf.json'}")
    return report


if __name__ == "__main__":
    main()
