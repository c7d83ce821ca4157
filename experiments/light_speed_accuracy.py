"""Speed/accuracy trade of the per-segment irradiance estimator, at the defaults users run.

    python experiments/light_speed_accuracy.py [--n-plants 16] [--optics prospect|paper]
        [--out experiments/results/light_speed_accuracy] [--replot]

One field and sun position (2016-04-20, 10:00 UTC at Selhausen, reconstructed weather), the
default leaf (PROSPECT-D, ``Optics.preset("prospect")``) and the default boundary (a periodic cell
of the measured plants). From the main job's settings (K = 32, the leaf's bounces for 1 %
truncation: 2, periodic, mesh 1 × 1, the direct light by projection with its default rays) one
knob is changed at a time — where the direct light comes from (the paths: the default before
issue 16's projection), the projection's rays per m² (sun, sky), samples K, bounces, mesh
resolution, the boundary (a finite field with 0–6 buffer rows and as many buffer plants along the
rows, the reference paper's setup at 2) and the accuracy knob ``target_rse`` (adaptive sampling,
:func:`~lightfit.light.estimator.render_adaptive`) — and absorbed PAR per segment and the canopy
total are compared with one reference: the mean of 8 seeds at K = 1024 (8 192 samples per
segment), 4 bounces, periodic, the direct light from the paths (an estimator independent of the
projection's rays; segments matched by plant
position and segment index, which do not depend on the boundary). Absorbed PAR uses that
moment's direct-normal and diffuse PAR as the coupled model takes them (``Forcing.of``: the
measured PAR, Spitters' diffuse share). Time is the wall time of the estimator (set-up and
render) on this machine's cores. Writes a CSV, a JSON and a Pareto plot (error against time), and prints a
table.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from rich.table import Table  # noqa: E402

import lightfit  # noqa: E402,F401
from lightfit.defaults import DEFAULT_RAYS_PER_M2
from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance, render_adaptive  # noqa: E402
from lightfit.light.scene import FieldScene, Optics  # noqa: E402
from lightfit.model.scenario import main_job_samples, resolve_direct  # noqa: E402
from lightfit.plant import Field, MeshResolution, build  # noqa: E402
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from periodic_vs_wide import light  # noqa: E402  (the moment and its PAR, one home for these experiments)
from provenance import wide_console, write_result  # noqa: E402  (commit, cores, load and command with every JSON)

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = dict(
    samples=1024, bounces=4, boundary="periodic", buffer_rows=0, along=1, across=1, target_rse=None, direct="paths"
)
#: Independent seeds averaged for the reference (K = 1024 each: 8 192 samples per segment in all;
#: one render at that K would hold ≈ 10 GB of paths). Its own median relative SE is reported: at
#: high K the errors below are mostly the reference's noise.
REFERENCE_SEEDS = tuple(range(12345, 12353))


def settings(optics: Optics) -> tuple[dict, list[dict]]:
    """The main job's settings for ``optics`` and the one-knob changes swept from them."""
    b = bounces_for_tolerance(0.01, optics)
    default = dict(samples=main_job_samples("projection"), bounces=b, boundary="periodic", buffer_rows=0)
    default |= dict(along=1, across=1, target_rse=None, direct="auto")
    default["rays"] = DEFAULT_RAYS_PER_M2
    sweep = (
        [{"direct": "paths", "samples": main_job_samples("paths")}]
        + [{"rays": r} for r in ((1e6, 1e7), (1e7, 1e7), (1e7, 3e7))]
        + [{"samples": k} for k in (8, 16, 64, 128, 256, 512)]
        + [{"bounces": d} for d in (0, 1, 2, 3, 4, 6) if d != b]
        + [{"boundary": "finite", "buffer_rows": r} for r in (0, 2, 4, 6)]
        + [{"along": 3, "across": 2}]
        + [{"target_rse": t} for t in (0.1, 0.05)]
    )
    return default, sweep


def _absorbed(
    n_plants: int, setting: dict, optics: Optics, sun: tuple[float, float], dni: float, dhi: float, seed: int
):
    if setting["boundary"] == "periodic":
        fld = Field(n_plants=n_plants, seed=1, boundary="periodic")
    else:
        r = setting["buffer_rows"]
        fld = Field(boundary="finite", n_plants=n_plants, seed=1, buffer_rows=r, buffer_along=r)
    geom = build(fld, resolution=MeshResolution(setting["along"], setting["across"]))
    fs = FieldScene(geom.mesh, optics, cell=geom.cell)
    fs.set_sun(*sun)
    seg = geom.segments[geom.segments["measured"]]
    ids = seg["segment_id"].to_numpy()
    direct = dict(direct=resolve_direct(setting["direct"], setting["boundary"]))
    if direct["direct"] == "projection":
        direct["direct_rays_per_m2"] = setting.get("rays", DEFAULT_RAYS_PER_M2)
    t0 = time.perf_counter()
    if setting["target_rse"] is None:
        est = SegmentEstimator(fs, ids, samples=setting["samples"], bounces=setting["bounces"], seed=seed, **direct)
        r = est.render()
        n_ev, k_mean = est.n_evaluations, float(est.samples)
    else:  # the pilot K is the setting's samples (at least 32)
        r = render_adaptive(
            fs,
            ids,
            setting["target_rse"],
            bounces=setting["bounces"],
            seed=seed,
            pilot=max(32, setting["samples"]),
            dni=dni,
            dhi=dhi,
            **direct,
        )
        n_ev, k_mean = r.meta["n_evaluations"], float(np.mean(r.meta["samples_per_segment"]))
    elapsed = time.perf_counter() - t0
    key = seg.set_index("segment_id").loc[r.segment_id]
    plants = fld.plants().set_index("plant_id").loc[key["plant_id"]]
    out = pd.DataFrame(
        {
            "r": plants["r"].to_numpy(),
            "c": plants["c"].to_numpy(),
            "segment_index": key["segment_index"].to_numpy(),
            "area_m2": r.meta["area_m2"],
            "is_blade": r.meta["is_blade"],
            "absorbed": r.total("absorbed", dni, dhi),
            "rse": r.relative_se("absorbed", dni, dhi),
        }
    ).set_index(["r", "c", "segment_index"])
    return out, elapsed, n_ev, k_mean


#: The value shown next to each point of the Pareto plot, per knob.
LABELS = {
    "samples": lambda r: f"K={r['samples']}",
    "bounces": lambda r: f"b={r['bounces']}",
    "boundary": lambda r: f"finite, {r['buffer_rows']} rows",
    "along,across": lambda r: f"mesh {r['along']}×{r['across']}",
    "target_rse": lambda r: f"target {r['target_rse']:.0%}",
    "direct": lambda r: f"direct from {r['direct']}",
    "direct,samples": lambda r: f"direct from {r['direct']}, K={r['samples']}",
    "rays": lambda r: "rays {:.0e}/{:.0e}".format(*r["rays"]),
    "default": lambda r: f"default (K={r['samples']}, b={r['bounces']})",
}


def _spread_labels(fig, texts) -> None:
    """Move point labels (annotations in offset points) apart: each, from the top down, takes the
    nearest offset beside its point where it overlaps no point and no label placed before it; a
    thin leader line joins a label moved away from its point."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()

    def box(t):  # the text alone: an annotation's own extent includes its leader line
        return matplotlib.text.Text.get_window_extent(t, renderer)

    def marker(t):
        x, y = t.axes.transData.transform(t.xy)
        return matplotlib.transforms.Bbox([[x - 4, y - 4], [x + 4, y + 4]])

    placed = [marker(t) for t in texts]  # labels keep off the points too
    for t in sorted(texts, key=lambda t: -t.axes.transData.transform(t.xy)[1]):
        width = box(t).width * 72 / fig.dpi
        offsets = [(dx, 3 + dy) for dx in (4, -4 - width, 12, -12 - width) for dy in range(-90, 91, 9)]
        offsets.sort(key=lambda o: (o[0] + (width / 2 if o[0] < 0 else 0)) ** 2 + o[1] ** 2)
        for dx, dy in [*offsets, (4, 3)]:  # nowhere free: where it was
            t.xyann = (dx, dy)
            if not any(box(t).overlaps(b) for b in placed):
                break
        placed.append(box(t))


def pareto(df: pd.DataFrame, n_plants: int, optics_name: str, path: Path) -> None:
    """Error against time, one line per knob, each point labelled with its value."""
    fig, ax = plt.subplots(1, 2, figsize=(13, 6), constrained_layout=True)
    texts = {a: [] for a in ax}
    for name, grp in df.groupby("changed"):
        grp = grp.sort_values("time_s")
        for a, col in zip(ax, ("median_rel_err_segment", "canopy_total_rel_err")):
            line = a.plot(grp["time_s"], grp[col], "o-" if len(grp) > 1 else "o", label=name)[0]
            for _, r in grp.iterrows():
                texts[a].append(
                    a.annotate(
                        LABELS[name](r),
                        (r["time_s"], r[col]),
                        xytext=(4, 3),
                        textcoords="offset points",
                        fontsize=7,
                        color=line.get_color(),
                        # a leader line, hidden under the marker unless the label is moved away
                        arrowprops=dict(arrowstyle="-", lw=0.5, color=line.get_color(), shrinkA=0, shrinkB=4),
                    )
                )
    for a, title in zip(ax, ("median per-segment error (segments with light)", "canopy-total error")):
        a.set_xscale("log")
        a.set_yscale("log")
        a.set_xlabel(f"wall time (s), {os.cpu_count()} CPU cores")
        a.set_ylabel("relative error against the reference")
        a.set_title(title)
        a.grid(True, which="both", alpha=0.3)
    ax[0].legend(title="knob changed from the default", fontsize=8)
    fig.suptitle(
        f"Absorbed PAR per segment, {n_plants} measured plants, {optics_name} leaf, periodic cell: speed against "
        f"accuracy (reference: K = 1024 × {len(REFERENCE_SEEDS)} seeds, {REFERENCE['bounces']} bounces)"
    )
    for t in texts.values():
        _spread_labels(fig, t)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def replot(out_dir: Path) -> None:
    """Redraw ``pareto.png`` from the ``sweep.csv`` and ``sweep.json`` a run wrote to ``out_dir``."""
    meta = json.loads((out_dir / "sweep.json").read_text())
    df = pd.read_csv(out_dir / "sweep.csv")
    df["rays"] = [ast.literal_eval(v) if isinstance(v, str) else None for v in df["rays"]]
    pareto(df, meta["n_plants"], meta["optics"], out_dir / "pareto.png")


def main(
    n_plants: int = 16,
    out_dir: Path = ROOT / "experiments" / "results" / "light_speed_accuracy",
    optics_name: str = "prospect",
) -> pd.DataFrame:
    out_dir.mkdir(parents=True, exist_ok=True)
    optics = Optics.preset(optics_name)
    default, sweep = settings(optics)
    sun, dni, dhi = light()  # the coupled model's PAR: the measured PAR, Spitters' diffuse share
    console = wide_console()
    console.print(
        f"sun {sun[0]:.1f}° / {sun[1]:.1f}°, PAR DNI {dni:.0f}, DHI {dhi:.0f} µmol m⁻² s⁻¹ (RECONSTRUCTED forcing); "
        f"leaf {optics_name}, default bounces {default['bounces']}"
    )
    parts = [_absorbed(n_plants, REFERENCE, optics, sun, dni, dhi, seed=s) for s in REFERENCE_SEEDS]
    ref = parts[0][0].copy()
    stack = np.stack([p[0]["absorbed"].to_numpy() for p in parts])
    ref["absorbed"] = stack.mean(0)
    # the reference's own relative SE: spread of the seeds' estimates / √seeds
    ref["rse"] = np.divide(
        stack.std(0, ddof=1) / np.sqrt(len(parts)),
        ref["absorbed"],
        out=np.full(len(ref), np.nan),
        where=stack.mean(0) > 0,
    )
    t_ref = sum(p[1] for p in parts)
    ref_total = float((ref["absorbed"] * ref["area_m2"]).sum())
    ref_rse = float(np.nanmedian(ref["rse"]))
    console.print(
        f"reference (K = 1024 × {len(parts)} seeds, {REFERENCE['bounces']} bounces, periodic): {t_ref:.1f} s, "
        f"its median relative SE {ref_rse:.2%}"
    )

    # Compile the projection's kernels (the reference's paths compiled the others) before timing.
    _absorbed(n_plants, {**default, "samples": 8, "direct": "projection"}, optics, sun, dni, dhi, seed=0)
    rows = []
    for change in [{}] + sweep:
        setting = {**default, **change}
        setting["direct"] = resolve_direct(setting["direct"], setting["boundary"])
        if setting["direct"] == "paths":
            setting["rays"] = None
        res, t, n_ev, k_mean = _absorbed(n_plants, setting, optics, sun, dni, dhi, seed=1)
        j = res.join(ref.add_suffix("_ref"), how="inner")
        lit = j["absorbed_ref"] > 1e-3 * j["absorbed_ref"].max()
        rel = (j["absorbed"] - j["absorbed_ref"]).abs()[lit] / j["absorbed_ref"][lit]
        blade = j["is_blade"][lit]
        total = float((res["absorbed"] * res["area_m2"]).sum())
        rows.append(
            {
                **setting,
                "changed": ",".join(k for k in change if k != "buffer_rows" or "boundary" not in change) or "default",
                "time_s": t,
                "evaluations": n_ev,
                "mean_samples": k_mean,
                "median_rel_err_segment": float(rel.median()),
                "p90_rel_err_segment": float(rel.quantile(0.9)),
                "median_rel_err_blades": float(rel[blade].median()),
                "median_rel_err_stems": float(rel[~blade].median()),
                "median_reported_rse": float(np.nanmedian(res["rse"][np.isfinite(res["rse"])])),
                "canopy_total_rel_err": abs(total - ref_total) / ref_total,
                "canopy_total_signed_rel_err": (total - ref_total) / ref_total,
            }
        )
        console.print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in rows[-1].items()})
    df = pd.DataFrame(rows)
    df.to_csv(out_dir / "sweep.csv", index=False)
    write_result(
        out_dir / "sweep.json",
        {
            "reference": REFERENCE,
            "reference_seeds": list(REFERENCE_SEEDS),
            "reference_time_s": t_ref,
            "reference_median_rse": ref_rse,
            "default": default,
            "optics": optics_name,
            "sun_deg": sun,
            "dni_par": dni,
            "dhi_par": dhi,
            "n_plants": n_plants,
            "rows": rows,
        },
    )
    pareto(df, n_plants, optics_name, out_dir / "pareto.png")
    t = Table(title="speed/accuracy (absorbed PAR, vs reference)")
    columns = (
        "changed",
        "direct",
        "samples",
        "bounces",
        "boundary",
        "buffer_rows",
        "along",
        "target_rse",
        "mean_samples",
        "time_s",
        "median_rel_err_segment",
        "p90_rel_err_segment",
        "median_rel_err_blades",
        "median_rel_err_stems",
        "median_reported_rse",
        "canopy_total_rel_err",
    )
    for c in columns:
        t.add_column(c, justify="right")
    for r in rows:
        t.add_row(*(f"{r[c]:.3g}" if isinstance(r[c], float) else str(r[c]) for c in columns))
    console.print(t)
    return df


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=16)
    ap.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "light_speed_accuracy")
    ap.add_argument("--optics", default="prospect", choices=["prospect", "paper"], help="leaf optics preset")
    ap.add_argument("--replot", action="store_true", help="redraw pareto.png from the sweep already in --out")
    a = ap.parse_args()
    if a.replot:
        replot(a.out)
    else:
        main(a.n_plants, a.out, a.optics)
