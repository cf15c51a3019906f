"""How closely the distance-field wall follows the lumen it was built from.

    python experiments/wall_field_check.py             # type1, 20,000 points
    python experiments/wall_field_check.py --aorta type3 --points 50000

Samples points within the contact range of the lumen surface (from 1.5 mm inside to
2.5 mm outside, along the faces' normals from random points on random triangles), reads
the sampled field there (`cathsim_dmc.sim.wall_field.distance`, as the contact test reads it)
and compares it with the exact signed distance to the same triangles (trimesh). Prints
the error's percentiles, how many points read no value, and the field's size and build
time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

from cathsim_dmc.anatomy import load_asset
from cathsim_dmc.anatomy.validate import open_end_plane
from cathsim_dmc.core.shipped import resolve_asset
from cathsim_dmc.sim import wall_field


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--aorta", default="type1")
    parser.add_argument("--points", type=int, default=20000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    asset = load_asset(resolve_asset(args.aorta))
    lumen = np.asarray([np.asarray(piece, dtype=float)[:3] for piece in asset.hulls])
    centre, outward, _ = open_end_plane(asset)
    begin = time.perf_counter()
    field = wall_field.build_field(lumen, shift_m=0.0, cut=(centre, outward))
    built_s = time.perf_counter() - begin

    rng = np.random.default_rng(args.seed)
    pick = rng.integers(len(lumen), size=args.points)
    weights = rng.dirichlet(np.ones(3), size=args.points)
    on_surface = np.einsum("ij,ijk->ik", weights, lumen[pick])
    normal = np.cross(lumen[pick, 1] - lumen[pick, 0], lumen[pick, 2] - lumen[pick, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    points = on_surface + rng.uniform(-2.5e-3, 1.5e-3, size=(args.points, 1)) * -normal  # + is into the lumen
    points = points[(points - centre) @ outward < -2e-3]  # away from the open end, where nothing is stored

    vertices, faces = np.unique(lumen.reshape(-1, 3).round(10), axis=0, return_inverse=True)
    mesh = trimesh.Trimesh(vertices, faces.reshape(-1, 3), process=False)
    _, exact_unsigned, triangle = trimesh.proximity.closest_point(mesh, points)
    read = wall_field.distance(field, points)
    known = np.isfinite(read)
    # trimesh's own sign is unreliable on an open surface: take the field's and check it
    # against the nearest face's side where the point lies clearly off the surface.
    error_m = np.abs(np.abs(read[known]) - exact_unsigned[known])
    side = np.einsum("ij,ij->i", points - mesh.triangles[triangle, 0], mesh.face_normals[triangle])
    clear = known & (exact_unsigned > 0.1e-3)
    wrong_sign = int(np.sum(np.sign(read[clear]) == np.sign(side[clear])))  # the field is positive inside
    index_entries = int(np.prod(field[5:8]))
    blocks = (len(field) - wall_field.HEADER - index_entries) // wall_field.BLOCK**3
    print(
        f"{args.aorta}: {len(lumen)} lumen triangles; field of {blocks} blocks ({field.nbytes / 1e6:.1f} MB), "
        f"built in {built_s:.2f} s"
    )
    print(f"{len(points)} points 1.5 mm inside to 2.5 mm outside the lumen; {int((~known).sum())} read no value")
    print(
        "|field| - exact distance, p50 / p99 / max (mm): "
        + " / ".join(f"{1e3 * v:.4f}" for v in np.percentile(error_m, [50, 99, 100]))
    )
    print(f"sign against the nearest face, points more than 0.1 mm off it: {wrong_sign} of {int(clear.sum())} wrong")


if __name__ == "__main__":
    main()
