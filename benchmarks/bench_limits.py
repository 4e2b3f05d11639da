"""How large an input cuboidlib handles: time and peak memory of reading, normals and distances.

Each case runs in a fresh process (so its peak resident memory is its own) on one thread, and
prints its wall time and peak memory. docs/limits.md and benchmarks/README.md quote these figures.

    python benchmarks/bench_limits.py            # all cases (about 2 minutes on one laptop core)
    python benchmarks/bench_limits.py --quick    # small sizes only, a smoke test
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import tempfile
import time
from pathlib import Path


def _text_cloud(folder: Path, n: int, normals: bool) -> Path:
    import numpy as np

    rng = np.random.default_rng(0)
    p = rng.random((n, 3))
    unit = rng.normal(size=(n, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)  # unit normals: read as normals (columns 4-6)
    cols = [p, unit] if normals else [p]
    path = folder / f"cloud_{n}_{'n' if normals else 'p'}.xyz"
    np.savetxt(path, np.concatenate(cols, axis=1), fmt="%.6f")
    return path


def _mesh(folder: Path, subdivisions: int) -> Path:
    import trimesh

    path = folder / f"sphere_{subdivisions}.ply"
    trimesh.creation.icosphere(subdivisions=subdivisions).export(path)
    return path


def case_read_text(folder: Path, n: int):
    from cuboidlib.io import read_point_cloud

    path = _text_cloud(folder, n, normals=True)
    start = time.perf_counter()
    read_point_cloud(path)
    return time.perf_counter() - start, f"read_point_cloud, {n:,} rows x 6 columns ({path.stat().st_size / 1e6:.0f} MB)"


def case_load_subsample(folder: Path, n: int):
    from cuboidlib.io import load_point_cloud

    path = _text_cloud(folder, n, normals=False)
    start = time.perf_counter()
    load_point_cloud(path, n_points=4096)
    return time.perf_counter() - start, f"load_point_cloud(n_points=4096), {n:,} points without normals"


def case_normals(folder: Path, n: int):
    import numpy as np

    from cuboidlib.normals import estimate_normals

    p = np.random.default_rng(0).random((n, 3))
    start = time.perf_counter()
    estimate_normals(p)
    return time.perf_counter() - start, f"estimate_normals, {n:,} points"


def case_mesh(folder: Path, subdivisions: int):
    import trimesh

    from cuboidlib.io import load_mesh_as_point_cloud

    path = _mesh(folder, subdivisions)
    faces = len(trimesh.load(path, process=False).faces)
    start = time.perf_counter()
    load_mesh_as_point_cloud(path, 4096)
    return time.perf_counter() - start, f"load_mesh_as_point_cloud(4096 points), mesh of {faces:,} triangles"


def case_open_mesh_at_limit(folder: Path, n: int):
    import trimesh

    from cuboidlib.io import load_mesh_as_point_cloud

    sphere = trimesh.creation.icosphere(subdivisions=5)
    path = folder / "open_sphere.ply"
    trimesh.Trimesh(sphere.vertices, sphere.faces[:-50], process=False).export(path)  # not watertight
    start = time.perf_counter()
    load_mesh_as_point_cloud(path, n)  # normals oriented by visibility: the costly path
    return time.perf_counter() - start, f"load_mesh_as_point_cloud({n:,} points; the limit MAX_SHAPE_POINTS is 20,000), an open mesh"


def case_collection(folder: Path, n_shapes: int):
    from cuboidlib.shapes import make_collection

    start = time.perf_counter()
    c = make_collection("chair", n_shapes, 4096, use_cache=False)
    return (time.perf_counter() - start,
            f"make_collection, {n_shapes:,} shapes x 4,096 points ({n_shapes * 4096:,} points; "
            f"MAX_COLLECTION_POINTS = 2^24 is 4,096 shapes), {c.points.nbytes / 1e6:.0f} MB of points")


def case_limits_refused(folder: Path, n: int):
    from cuboidlib.io import load_mesh_as_point_cloud
    from cuboidlib.train_config import TrainConfig

    path = _mesh(folder, 3)
    start = time.perf_counter()
    for attempt in (lambda: load_mesh_as_point_cloud(path, n), lambda: TrainConfig(n_shapes=n),
                    lambda: TrainConfig(n_points=n)):
        try:
            attempt()
        except ValueError:
            pass
        else:
            raise AssertionError(f"{n:,} was not refused")
    return time.perf_counter() - start, f"refusing {n:,} points / shapes above the limits (mesh, config)"


def case_chamfer(folder: Path, n: int):
    import torch

    from cuboidlib.distance import chamfer_distance

    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(1, n, 3, generator=g), torch.rand(1, n, 3, generator=g)
    start = time.perf_counter()
    chamfer_distance(a, b)
    return time.perf_counter() - start, f"chamfer_distance, {n:,} against {n:,} points"


def _child(case, size, queue):
    import torch

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as folder:
        seconds, what = case(Path(folder), size)
    queue.put((seconds, what, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024))


def run(case, size) -> tuple[float, str, float]:
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_child, args=(case, size, queue))
    proc.start()
    result = queue.get()
    proc.join()
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small sizes only")
    args = parser.parse_args()
    if args.quick:
        cases = [(case_read_text, 10_000), (case_load_subsample, 10_000), (case_normals, 2_000),
                 (case_mesh, 4), (case_chamfer, 10_000), (case_open_mesh_at_limit, 2_000), (case_collection, 8),
                 (case_limits_refused, 10**9)]
    else:
        from cuboidlib._checks import MAX_COLLECTION_POINTS, MAX_SHAPE_POINTS

        cases = [(case_read_text, 1_000_000), (case_load_subsample, 1_000_000), (case_normals, 5_000),
                 (case_normals, 20_000), (case_mesh, 8), (case_chamfer, 100_000),
                 (case_open_mesh_at_limit, MAX_SHAPE_POINTS), (case_collection, MAX_COLLECTION_POINTS // 4096),
                 (case_limits_refused, 10**9)]
    print(f"{'seconds':>8s}  {'peak MB':>8s}  case (one thread; peak = resident memory of the whole process)")
    for case, size in cases:
        seconds, what, peak_mb = run(case, size)
        print(f"{seconds:8.2f}  {peak_mb:8.0f}  {what}", flush=True)


if __name__ == "__main__":
    main()
