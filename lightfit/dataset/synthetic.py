"""A small *synthetic* results file in the coupled model's format, for tests, demos and benchmarks.

The values are not a model run: absorbed PAR grows with segment height under the day's PAR,
Vj follows a saturating light response, Vc is constant per plant, An = min(Vc, Vj) − Rd, and
gs ∝ An on the leaf blades; stems and sheaths have what a run writes there (NaN, limitation −1:
:func:`lightfit.model.schema.on_segments`). The dataset's attrs say ``synthetic = "true"`` so
nothing downstream mistakes it for model output.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.model import schema


def synthetic_results(fld, times, *, seed: int = 0, cache_dir=None, measured_only: bool = True):
    """An ``xarray.Dataset`` (time, segment) for ``fld`` (a :class:`lightfit.plant.Field`) at UTC ``times``."""
    import xarray as xr

    from lightfit import weather
    from lightfit.plant import build, centre_height_m

    times = pd.DatetimeIndex(times)
    times = times.tz_localize("UTC") if times.tz is None else times.tz_convert("UTC")
    if len(times) == 0:
        raise InputError("no times", parameter="times", expected="at least one UTC timestamp")
    seg = build(fld, cache_dir=cache_dir).segments
    if measured_only:
        seg = seg[seg["measured"]]
    rng = np.random.default_rng(seed)
    sun = weather.solar_position(times)
    par_top = 2000.0 * np.clip(np.sin(np.radians(sun["sun_elevation_deg"].to_numpy())), 0.0, None)  # µmol m-2 s-1
    height = np.maximum(centre_height_m(seg), 0.0)
    rel = np.clip(height / max(height.max(), 1e-9), 0.0, 1.0) ** 2
    shade = rng.uniform(0.3, 1.0, size=len(seg))
    par = 0.85 * par_top[:, None] * (0.05 + 0.95 * rel * shade)[None, :]
    vc_plant = pd.Series(rng.uniform(12.0, 26.0, size=seg["plant_id"].nunique()), index=np.unique(seg["plant_id"]))
    vc = np.broadcast_to(vc_plant.reindex(seg["plant_id"]).to_numpy()[None, :], par.shape).copy()
    vj = 40.0 * par / (par + 600.0)
    an = np.minimum(vc, vj) - 1.0
    gs = np.clip(0.01 + 0.012 * an, 0.01, None)
    dims, on_segment = ("time", "segment"), schema.segment_coords(seg)
    blade = on_segment["is_blade"][1]
    leaf = {
        "leaf_an_umol_m2_s": an,
        "leaf_vc_umol_m2_s": vc,
        "leaf_vj_umol_m2_s": vj,
        "leaf_gs_mol_m2_s": gs,
        "limitation": vj < vc,
    }
    ds = xr.Dataset(
        {
            "absorbed_par_umol_m2_s": (dims, par),
            **{k: (dims, schema.on_segments(k, v[:, blade], blade)) for k, v in leaf.items()},
        },
        coords={"time": times.tz_convert(None).to_numpy(), **on_segment},
        attrs={
            **fld.attrs(),
            "synthetic": "true",
            "title": "lightfit synthetic results (not a model run)",
        },
    )
    return schema.annotate(ds)
