"""What taking the sun at the centre of each 10-minute mean changes on a real TERENO day.

    python experiments/interval_centres.py [--full] [--out experiments/results/interval_centres.json]

Two days, each read twice:

* ``real``: the bundled real day (CPlantBox's Selhausen file, ``selhausen-cplantbox-day``, placed
  on 2016-04-27 as in the README; 06:00 + 14 h local), an overcast day;
* ``clear``: a clear day as a logger would record it: the 20 April 2016 reconstruction computed
  minute by minute (``reconstruct_day(step="1min")``) and averaged into 10-minute means stamped at
  their ends (synthetic, from the reconstruction's assumptions; 05:00 + 14 h local).

``end`` reads the stamps as the ends of 10-minute means (the default since this change: the sun
five minutes before each stamp); ``instant`` reads them with ``time_label="center"``, which puts
the sun at the stamps, what lightfit did for every file before (both days have CO2 on every row,
so nothing else differs). 30-minute steps are sub-sampled as the main job does.

Both run the same model (the quick configuration unless ``--full``: the main job's), with the
same plants and render seeds, so the differences are the sun's five minutes, not Monte Carlo
noise. Reports per step the sun's elevation, the beam's share of the horizontal PAR, the mean PAR
at the plants and the canopy's net CO2 uptake, and the day's sums; writes JSON and prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from rich.table import Table

from lightfit import replication as rep
from lightfit import weather
from lightfit.precision import use_float64
from lightfit.weather.site import Window
from lightfit.weather.timestamps import Timestamps

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from provenance import wide_console, write_result  # noqa: E402  (commit, cores, load and command with every JSON)

OUT = Path(__file__).resolve().parent / "results" / "interval_centres.json"
DAYS = {  # name: (date, window)
    "real": ("2016-04-27", Window("06:00", 14.0, "30min")),
    "clear": ("2016-04-20", Window("05:00", 14.0, "30min")),
}
TEN = pd.Timedelta("10min")


def clear_logger_day(date: str) -> pd.DataFrame:
    """The reconstruction's 1-min instants averaged into 10-min means stamped at their ends: the
    trapezoid rule over the minutes T − 10 … T, i.e. the mean over (T − 10 min, T] to second order.
    (Until this was corrected the mean took the minutes T − 10 … T − 1, 30 s early.)"""
    fine = weather.reconstruct_day(date, step="1min")
    cols = [c for c in fine.columns if c in weather.BOUNDS]
    minute = (fine[cols] + fine[cols].shift(1)) / 2  # at t: the trapezoid mean over (t − 1 min, t]
    means = minute.resample(TEN, closed="right", label="right").mean()
    means = means.iloc[1:-1]  # whole intervals only
    means.attrs = {"source": "20 April reconstruction, 1-min, as 10-min end-stamped means", "provenance": "synthetic"}
    return means


def forcing(cfg: rep.ReplicationConfig, day: str, time_label: str):
    date = cfg.dates[0]
    if day == "real":
        src = weather.read_source("selhausen-cplantbox-day", date=date, time_label=time_label)
    else:
        src = clear_logger_day(date)
        src.attrs["timestamps"] = Timestamps(time_label, TEN)
    src = weather.add_solar(src, site=cfg.site)
    t0, _ = cfg.window.bounds_utc(date, cfg.site.timezone)
    return weather.window(src, t0, cfg.window.hours, cfg.window.step, how=cfg.how)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="the main job's configuration (default: quick)")
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    base = rep.ReplicationConfig() if a.full else rep.ReplicationConfig.quick()
    out = {
        "made_by": "python experiments/interval_centres.py" + (" --full" if a.full else ""),
        "config": "full" if a.full else "quick",
        "days": {},
    }
    console = wide_console()
    for day, (date, win) in DAYS.items():
        cfg = dataclasses.replace(base, dates=(date,), window=win)
        runs = {}
        for label, time_label in (("end", "end"), ("instant", "center")):
            w = forcing(cfg, day, time_label)
            ds, _ = rep.run(cfg, forcing_df=w, observations=None, progress=True)
            ghi = w["ghi_w_m2"].to_numpy()
            beam = w["dni_w_m2"].to_numpy() * np.sin(np.radians(w["sun_elevation_deg"].clip(lower=0).to_numpy()))
            runs[label] = {
                "sun_elevation_deg": w["sun_elevation_deg"].to_numpy(),
                "beam_share": np.divide(beam, ghi, out=np.zeros_like(ghi), where=ghi > 0),
                "plant_par_umol_m2_s": ds["plant_par_umol_m2_s"].to_numpy(),
                "canopy_an_umol_m2_s": ds["canopy_an_umol_m2_s"].to_numpy(),
                "canopy_an_mc_sd_umol_m2_s": ds["canopy_an_mc_sd_umol_m2_s"].to_numpy(),
            }
            times = [str(t) for t in w.index]
        e, i = runs["end"], runs["instant"]
        sums = {
            k: {"end": float(e[k].sum()), "instant": float(i[k].sum()), "change": float(e[k].sum() / i[k].sum() - 1)}
            for k in ("plant_par_umol_m2_s", "canopy_an_umol_m2_s")
        }
        out["days"][day] = {
            "date": date,
            "window": dataclasses.asdict(win),
            "source": str(w.attrs.get("source")),
            "time_utc": times,
            "runs": {k: {q: v.tolist() for q, v in r.items()} for k, r in runs.items()},
            "day_sums": sums,
        }
        t = Table(title=f"{day} day {date}: the sun at the centres of 10-min means (end) against the stamps (instant)")
        for c in ("UTC", "sun ° end / instant", "beam share end / instant", "plant PAR end / instant", "canopy An Δ %"):
            t.add_column(c, justify="right")
        for k, ts in enumerate(times):
            an_i = i["canopy_an_umol_m2_s"][k]
            d_an = (e["canopy_an_umol_m2_s"][k] / an_i - 1) * 100 if abs(an_i) > 0.5 else float("nan")
            t.add_row(
                ts[11:16],
                f"{e['sun_elevation_deg'][k]:.2f} / {i['sun_elevation_deg'][k]:.2f}",
                f"{e['beam_share'][k]:.3f} / {i['beam_share'][k]:.3f}",
                f"{e['plant_par_umol_m2_s'][k]:.1f} / {i['plant_par_umol_m2_s'][k]:.1f}",
                f"{d_an:+.2f}",
            )
        console.print(t)
        for k, v in sums.items():
            console.print(
                f"{day}: day's sum of {k}: {v['end']:.1f} against {v['instant']:.1f} ({v['change'] * 100:+.2f} %)"
            )
    a.out.parent.mkdir(parents=True, exist_ok=True)
    write_result(a.out, out, indent=1)
    console.print(f"→ {a.out}")


if __name__ == "__main__":
    main()
