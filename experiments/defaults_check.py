"""Issue 14's done-when checks of the credible default leaf, measured by the code.

    python experiments/defaults_check.py [--full] [--parts leaf,bounces,canopy,gallery]

1. **Leaf**: PAR absorptance of an isolated horizontal leaf (10 cm square, 1 m above black soil)
   under a uniform sky, measured with the light estimator (K = 2048, 3 bounces), for the default
   (``prospect``) and the ``paper`` leaf; checked against PROSPECT-D's 0.83–0.92 for wheat.
2. **Bounces**: canopy-total absorbed PAR at 12:00 local on 20 April against the scattering
   orders (0 … 8) on the quick field and, with ``--full``, the main job's default field (both
   periodic), for both leaves, with common random numbers (same seed: the first b orders of
   every path are the same), next to :func:`lightfit.light.estimator.bounces_for_tolerance`.
3. **Canopy**: night-time and noon canopy net CO2 exchange per ground area of the default
   configuration (quick; with ``--full`` also the main job's size) and of the ``paper`` preset,
   by :func:`experiments.photosynthesis_default_check.canopy`, with the fraction of
   Rubisco-limited blades at noon, all blades and the sunlit ones (direct beam ≥ half of the
   blade's incident PAR).
4. **Gallery**: the data scene (:mod:`lightfit.dataset`) of the quick default run at its
   highest sun: the share of Rubisco-limited leaf pixels in the labels of the gallery's images
   (both classes must show).

Prints Markdown tables and writes ``--out`` (default experiments/results/defaults_check.json).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from provenance import write_result  # noqa: E402  (commit, cores, load and command with every JSON)

import lightfit.photosynthesis as ps  # noqa: E402
from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance  # noqa: E402
from lightfit.light.leaf_optics import par_optics  # noqa: E402
from lightfit.light.scene import FieldScene, Optics  # noqa: E402
from lightfit.model.coupled import CoupledModel  # noqa: E402
from lightfit.plant.mesh import Mesh  # noqa: E402
from lightfit.replication import ReplicationConfig, forcing, run, scenario_for  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from photosynthesis_default_check import NIGHT_RANGE, NOON_RANGE, canopy  # noqa: E402

LEAF_RANGE = (0.83, 0.92)
BOUNCES = (0, 1, 2, 3, 4, 6, 8)
NOON_LOCAL = "2016-04-20 12:00"


def isolated_leaf(preset: str, samples: int = 2048) -> dict:
    """Absorptance and transmittance of a lone horizontal leaf under a uniform sky (black soil)."""

    def square(h, z):
        return np.array([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]], float)

    faces = np.array([[0, 1, 2], [0, 2, 3]])
    # leaf (id 7) and a 2 cm sensor 1 mm below it (id 8), which sees the leaf's transmitted light
    mesh = Mesh(
        np.vstack([square(0.05, 1.0), square(0.01, 0.999)]),
        np.vstack([faces, faces + 4]),
        np.array([7, 7, 8, 8]),
        np.ones(4, bool),
    )
    fs = FieldScene(mesh, Optics.preset(preset, soil_albedo=0.0), sky="isotropic")
    fs.set_sun(60.0, 180.0)
    r = SegmentEstimator(fs, [7, 8], samples=samples, bounces=3, seed=0).render()
    a = float(r.absorbed_sky[0] / r.incident_sky[0])
    return {
        "preset": preset,
        "absorptance": a,
        "absorptance_se": float(r.se["absorbed_sky"][0] / r.incident_sky[0]),
        "transmitted_below": float(r.incident_sky[1]),
        "prospect_d_absorptance": par_optics().A if preset == "prospect" else None,
        "in_range": bool(LEAF_RANGE[0] <= a <= LEAF_RANGE[1]),
    }


def bounce_convergence(cfg: ReplicationConfig, label: str, samples: int = 32) -> list[dict]:
    """Canopy-total absorbed PAR (µmol s⁻¹ over the measured plants) at noon against the bounces."""
    w = forcing(None, cfg.how)
    noon = w.index.tz_convert("Europe/Berlin") == pd.Timestamp(NOON_LOCAL, tz="Europe/Berlin")
    w = w[noon]
    rows = []
    for preset in ("prospect", "paper"):
        sc = scenario_for(ReplicationConfig(**{**cfg.__dict__, "optics": preset}), w)
        m = CoupledModel(sc)
        fs = FieldScene(m.geometry.mesh, sc.optics, sky=sc.sky, cell=m.geometry.cell)
        fs.set_sun(float(w["sun_elevation_deg"].iloc[0]), float(w["sun_azimuth_deg"].iloc[0]))
        fs.freeze_sampling()
        f = m.forcing
        area = dict(zip(m.segment_id, m.area_m2))
        totals = {}
        for b in BOUNCES:
            t0 = time.perf_counter()
            r = SegmentEstimator(fs, m.segment_id, samples=samples, bounces=b, seed=0).render()
            a = np.array([area[s] for s in r.segment_id])
            dni, dhi = float(f.dni_par[0]), float(f.dhi_par[0])
            tot = float(a @ r.total("absorbed", dni, dhi))
            se = float(np.sqrt(np.sum((a * dni * r.se["absorbed_sun"]) ** 2 + (a * dhi * r.se["absorbed_sky"]) ** 2)))
            totals[b] = (tot, se, time.perf_counter() - t0)
        ref = totals[max(BOUNCES)][0]
        for b, (tot, se, sec) in totals.items():
            rows.append(
                {
                    "field": label,
                    "optics": preset,
                    "bounces": b,
                    "canopy_absorbed_par_umol_s": tot,
                    "mc_se_umol_s": se,
                    "change_vs_8_bounces": tot / ref - 1.0,
                    "seconds": sec,
                    "samples": samples,
                }
            )
        rows.append(
            {
                "field": label,
                "optics": preset,
                "bounces_for_tolerance": {str(t): bounces_for_tolerance(t, sc.optics) for t in (1e-2, 3e-3, 1e-3)},
            }
        )
    return rows


def sunlit_rubisco_fraction(cfg: ReplicationConfig) -> dict:
    """Rubisco-limited share of all and of sunlit blades at 12:00 local (sunlit: beam ≥ ½ of incident PAR)."""
    w = forcing(None, cfg.how)
    noon = w.index.tz_convert("Europe/Berlin") == pd.Timestamp(NOON_LOCAL, tz="Europe/Berlin")
    m = CoupledModel(scenario_for(cfg, w[noon]))
    th = m.scenario.theta
    vals, _ = m.parts(th)  # (1, 4, S): incident sun, incident sky, absorbed sun, absorbed sky per unit DNI/DHI
    v = np.asarray(vals)[0][:, : len(m.is_blade)]  # the segments (sensor columns follow them)
    beam = v[0] * m.forcing.dni_par[0]
    sunlit = beam >= 0.5 * (beam + v[1] * m.forcing.dhi_par[0])
    lim = np.asarray(m.observe(th)["photosynthesis"].limitation)[0]
    b = m.is_blade
    sl = sunlit[b]
    return {
        "blades": int(b.sum()),
        "sunlit_blades": int(sl.sum()),
        "rubisco_limited_all": float((lim == ps.RUBISCO_LIMITED).mean()),
        "rubisco_limited_sunlit": float((lim[sl] == ps.RUBISCO_LIMITED).mean()) if sl.any() else None,
        "rubisco_limited_shaded": float((lim[~sl] == ps.RUBISCO_LIMITED).mean()) if (~sl).any() else None,
    }


def gallery_fractions(cfg: ReplicationConfig) -> dict:
    """Share of Rubisco-limited leaf pixels in the data scene's gallery at the highest sun."""
    from lightfit.dataset import DatasetSpec, make_dataset
    from lightfit.dataset.camera import Sweep
    from lightfit.dataset.render import RenderSettings
    from lightfit.replication import write_netcdf

    with tempfile.TemporaryDirectory() as tmp:
        ds, _ = run(cfg, observations=None)
        write_netcdf(ds, Path(tmp) / "results.nc")
        spec = DatasetSpec(
            sweep=Sweep(n=2, camera={"width_px": 96, "height_px": 96}),
            settings=RenderSettings(spp=4, colour="mono"),
            gallery_images=2,
            export="none",
        )
        meta = make_dataset(Path(tmp) / "results.nc", Path(tmp) / "ds", spec)
        rows = []
        for img in meta["images"]:
            lab = np.load(Path(tmp) / "ds" / img["labels"])
            lim = lab["limitation"][(lab["organ"] == 3) & (lab["limitation"] >= 0)]
            rows.append(
                {
                    "image": img["labels"],
                    "leaf_pixels_with_values": int(lim.size),
                    "rubisco_limited_pixels": float((lim == ps.RUBISCO_LIMITED).mean()) if lim.size else None,
                }
            )
    return {"time_utc": meta["images"][0]["time_utc"], "images": rows}


def main(full: bool = False, parts: str = "leaf,bounces,canopy,gallery", out_path: Path | None = None) -> dict:
    todo = set(parts.split(","))
    quick = ReplicationConfig.quick()
    out: dict = {"ranges": {"leaf_absorptance": LEAF_RANGE, "night": NIGHT_RANGE, "noon": NOON_RANGE}}
    if "leaf" in todo:
        out["leaf"] = [isolated_leaf(p) for p in ("prospect", "paper")]
        print("| leaf | absorptance (estimator) | ± SE | PROSPECT-D | in 0.83–0.92 |")
        print("|---|---:|---:|---:|---|")
        for r in out["leaf"]:
            pd_a = "–" if r["prospect_d_absorptance"] is None else f"{r['prospect_d_absorptance']:.3f}"
            print(f"| {r['preset']} | {r['absorptance']:.3f} | {r['absorptance_se']:.3f} | {pd_a} | {r['in_range']} |")
    if "bounces" in todo:
        fields = {"quick (4 plants, periodic)": quick}
        if full:
            fields["default (100 plants, periodic)"] = ReplicationConfig()
        out["bounces"] = [r for k, c in fields.items() for r in bounce_convergence(c, k)]
        print("\n| field | leaf | bounces | canopy absorbed PAR (µmol s⁻¹) | ± MC SE | change vs 8 | s |")
        print("|---|---|---:|---:|---:|---:|---:|")
        for r in out["bounces"]:
            if "bounces" in r:
                print(
                    f"| {r['field']} | {r['optics']} | {r['bounces']} | {r['canopy_absorbed_par_umol_s']:.1f} "
                    f"| {r['mc_se_umol_s']:.1f} | {100 * r['change_vs_8_bounces']:+.2f} % | {r['seconds']:.1f} |"
                )
            else:
                print(f"| {r['field']} | {r['optics']} | bounces_for_tolerance {r['bounces_for_tolerance']} | | | | |")
    if "canopy" in todo:
        configs = {"quick": quick}
        if full:
            configs["default"] = ReplicationConfig()
        canopy_rows = {}
        for k, c in configs.items():
            for preset in ("default", "paper"):
                cfg = c.with_preset(preset)
                r = canopy(cfg, cfg.photosynthesis)
                r["optics"] = cfg.optics
                r["noon_sunlit"] = sunlit_rubisco_fraction(cfg)
                canopy_rows[f"{k}, {preset}"] = r
        out["canopy"] = canopy_rows
        print("\n| configuration | night canopy An | noon canopy An (12–14 h) | Rubisco-limited blades at 12:00 |")
        print("|---|---:|---:|---:|")
        for k, r in canopy_rows.items():
            s = r["noon_sunlit"]
            sun = "–" if s["rubisco_limited_sunlit"] is None else f"{100 * s['rubisco_limited_sunlit']:.0f} %"
            print(
                f"| {k} | {r['night_mean_umol_m2_s']:.2f} | {r['noon_mean_umol_m2_s']:.1f} "
                f"| {100 * s['rubisco_limited_all']:.0f} % / {sun} ({s['sunlit_blades']} of {s['blades']} sunlit) |"
            )
    if "gallery" in todo:
        out["gallery"] = gallery_fractions(quick)
        print(f"\ngallery ({out['gallery']['time_utc']} UTC): Rubisco-limited share of leaf pixels")
        for r in out["gallery"]["images"]:
            print(f"  {r['image']}: {r['rubisco_limited_pixels']} of {r['leaf_pixels_with_values']} leaf pixels")
    path = ROOT / "experiments" / "results" / "defaults_check.json" if out_path is None else out_path
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():  # keep the parts not rerun
        out = {**json.loads(path.read_text()), **out}
    out["made_by"] = "python experiments/defaults_check.py" + (" --full" if full else "") + f" --parts {parts}"
    write_result(path, out, default=float)
    print(f"\nwrote {path}")
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="also the main job's default field (slower)")
    ap.add_argument("--parts", default="leaf,bounces,canopy,gallery", help="comma-separated parts to run")
    ap.add_argument(
        "--out",
        dest="out_path",
        type=Path,
        default=None,
        help="JSON to write (default experiments/results/defaults_check.json)",
    )
    main(**vars(ap.parse_args()))
