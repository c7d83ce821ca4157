"""Run LESS 3 (``less3d``) on a field exported by ``benchmarks/bench_less.py``.

    .venv-less/bin/python benchmarks/less_runner.py EXPORT_DIR [PERMUTATION_SEED]

Runs under the separate LESS environment (``.venv-less``, see README "Optional: LESS 3 peer"):
it imports ``less`` and numpy only, never lightfit. LESS is a benchmark peer, never a lightfit
dependency: its licence (LESS Academic and Non-Commercial Research License 1.0) allows
non-commercial research and evaluation only.

Input, written by bench_less.py into EXPORT_DIR:

- ``mesh.npz``: ``triangles`` (F, 3, 3) float64, m, lightfit axes (x east, y north, z up; soil
  z = 0), counter-clockwise around lightfit's face normal (the front side);
  ``ground`` (4, 3) corners of the soil quad, which spans [0, W] × [0, D] (the scene size);
- ``job.json``: optics (``reflectance``, ``transmittance`` per leaf side, ``soil_albedo``), sun
  (``zenith_deg``, ``azimuth_deg`` clockwise from north), ``max_depth``, ``repetitive`` (0 or a
  wrap count), ``scene_size_m`` (x, y), and ``runs``: a list of
  ``{"label", "n_samples", "permutation_seed", "dni", "dhi"}``.

Output: ``EXPORT_DIR/out/<label>.npz`` with ``top`` and ``bot`` (F,) absorbed irradiance per
unit area of each triangle side in the units of the run's dni/dhi (``top`` is lightfit's front
side), ``simulate_s`` (wall time of ``scene.simulate``) and ``build_s``.

What LESS does and how this maps it (measured on less3d 3.0.7, Embree backend, documented in
docs/light.md "Peer: LESS 3"):

- ``RadiationFieldProcess`` (reverse ray tracing) traces ``n_samples`` hemisphere samples per
  triangle side with up to ``max_depth`` scattering events and returns absorbed W m⁻² on both
  sides of every primitive. It has no seed: its random streams are keyed by primitive index,
  so each replicate writes the triangles in a different order (``permutation_seed``) and the
  results are put back in the original order.
- Its OBJ loader is y-up and its scene is seen from the other side: a vertex written as
  (W − x, z, y), W the scene width, lands where the sun (zenith, azimuth clockwise from north)
  lights it as lightfit does — checked with the shadow of a wall placed north, and one placed
  east, of a small leaf, sun from each side — and LESS's ``absorbed_bot`` is then the side
  lightfit's counter-clockwise face normal points to (a wall facing north, lit from the north;
  a leaf facing down, lit from above on its ``absorbed_top``). The output ``top`` here is
  lightfit's front side.
- The ``Terrain`` is not seen by rays leaving leaves in this process (a leaf facing the soil
  received no soil-reflected sun, and full sky from below): the soil is therefore an explicit
  opaque Lambertian quad in the mesh, wide enough (bench_less.py) that rays missing it are
  negligible.
- Each triangle is written with its own three vertices: LESS smooths vertex normals across
  shared vertices (dihedral angle < 60°), lightfit's faces are flat.
- One PAR band (550 nm centre, 1 nm wide) with a flat top-of-atmosphere spectrum of 1 W m⁻² nm⁻¹
  and ``PrescribedAtmosphere``: direct-beam transmittance ``a`` gives DNI = a, diffuse
  transmittance ``b`` an isotropic sky with DHI = b·cos(zenith).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

#: How to get LESS 3 and on what terms: said by every script that stops without it.
LESS_HOW = (
    "LESS 3 (PyPI less3d) is an optional benchmark peer, never a lightfit dependency: install it in "
    "its own environment with `python -m venv .venv-less && .venv-less/bin/pip install less3d==3.0.7` "
    "(or set LIGHTFIT_LESS_PYTHON to a Python that has it). Its licence, the LESS Academic and "
    "Non-Commercial Research License 1.0, allows teaching and non-commercial research and evaluation "
    "only; commercial use needs a separate licence from its authors (README, 'Optional: LESS 3 peer')."
)


def write_obj(path: Path, triangles: np.ndarray, ground: np.ndarray, width_m: float) -> None:
    """Plant triangles (group ``plant``) and the soil quad (group ``soil``) in LESS's OBJ axes:
    lightfit's (x, y, z) is written as (width − x, z, y), a rotation (windings keep their sense)."""
    n = len(triangles)
    v = np.concatenate([triangles.reshape(-1, 3), ground])
    v = np.stack([width_m - v[:, 0], v[:, 2], v[:, 1]], axis=1)
    f = np.arange(3 * n).reshape(n, 3) + 1
    g = 3 * n + 1
    with open(path, "w") as fh:
        fh.write("g plant\n")
        np.savetxt(fh, v, fmt="v %.7f %.7f %.7f")
        np.savetxt(fh, f, fmt="f %d %d %d")
        fh.write(f"g soil\nf {g} {g + 1} {g + 2}\nf {g} {g + 2} {g + 3}\n")


def main(export: Path, only_seed: int | None = None) -> None:
    """Run the job's runs (only those of ``only_seed``, one face order, when given)."""
    import less
    from less.spectral_profile import SpectralBand, SpectralProfile

    job = json.loads((export / "job.json").read_text())
    mesh = np.load(export / "mesh.npz")
    tri, ground = mesh["triangles"], mesh["ground"]
    n = len(tri)
    out = export / "out"
    out.mkdir(exist_ok=True)
    o = job["optics"]
    sun = job["sun"]
    cosz = math.cos(math.radians(sun["zenith_deg"]))
    band = SpectralProfile([SpectralBand(550.0, 1.0, "par")])
    built: dict[int, tuple] = {}
    for run in job["runs"]:
        seed = int(run["permutation_seed"])
        if only_seed is not None and seed != only_seed:
            continue
        if seed not in built:
            built.clear()  # one scene at a time (memory)
            perm = np.arange(n) if seed == 0 else np.random.default_rng(seed).permutation(n)
            obj_path = export / f"scene_{seed}.obj"
            for stale in (obj_path, Path(str(obj_path) + ".npz")):
                if stale.exists():
                    os.remove(stale)
            write_obj(obj_path, tri[perm], ground, float(job["scene_size_m"][0]))
            t0 = time.perf_counter()
            plant = less.Object("field", mesh=str(obj_path))
            plant.set_property("plant", less.Lambertian(reflectance=o["reflectance"], transmittance=o["transmittance"]))
            plant.set_property("soil", less.Lambertian(reflectance=o["soil_albedo"]))
            scene = less.Scene(backend="embree")
            scene.size = tuple(job["scene_size_m"])
            scene.repetitive = int(job["repetitive"])  # 0: finite; else the wrap-count cap
            scene.add(plant, positions=[(0.0, 0.0, 0.0)])
            scene.illumination = less.Illumination(
                source=less.Sun(zenith=sun["zenith_deg"], azimuth=sun["azimuth_deg"], irradiance=1.0),
                atmosphere=less.NoAtmosphere(),
            )
            scene.build()
            built[seed] = (scene, perm, time.perf_counter() - t0)
        scene, perm, build_s = built[seed]
        a, b = float(run["dni"]), float(run["dhi"]) / cosz
        if a + b > 1 + 1e-9:  # transmittances must not sum above 1: scale both, undo after
            scale = a + b
            a, b = a / scale, b / scale
        else:
            scale = 1.0
        scene.illumination = less.Illumination(
            source=less.Sun(zenith=sun["zenith_deg"], azimuth=sun["azimuth_deg"], irradiance=1.0),
            atmosphere=less.PrescribedAtmosphere(direct_beam_transmittance=a, diffuse_horizontal_transmittance=b),
        )
        proc = less.RadiationFieldProcess(
            spectral_profile=band, n_samples=int(run["n_samples"]), max_depth=int(job["max_depth"])
        )
        t0 = time.perf_counter()
        r = scene.simulate(proc)
        dt = time.perf_counter() - t0
        top = np.empty(n)
        bot = np.empty(n)
        # LESS's "bottom" side is the side lightfit's face normal points to (see above).
        top[perm] = r.absorbed_bot[:n, 0] * scale
        bot[perm] = r.absorbed_top[:n, 0] * scale
        np.savez(out / f"{run['label']}.npz", top=top, bot=bot, simulate_s=dt, build_s=build_s)
        print(f"{run['label']}: n={run['n_samples']} simulate {dt:.2f} s", flush=True)


if __name__ == "__main__":
    import argparse
    import importlib.util

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("export", type=Path, help="the folder bench_less.py exported the field into")
    ap.add_argument("permutation_seed", type=int, nargs="?", help="run only this face order's runs")
    a = ap.parse_args()
    if importlib.util.find_spec("less") is None:  # run by bench_less.py with .venv-less's Python
        sys.exit(f"less_runner.py needs LESS 3 (less3d) in the Python that runs it. {LESS_HOW}")
    main(a.export, a.permutation_seed)
