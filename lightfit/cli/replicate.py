"""``lightfit replicate``: the main job, the 20 April 2016 Selhausen replication."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from rich.table import Table

from lightfit.cli.common import console, parse_theta, weather_report, weather_table
from lightfit.cli.options import ModelOptions, model_options, resolve, weather


@model_options
def replicate(
    out: Path = typer.Option(Path("results/2016-04-20"), help="Output directory."),
    observations: Path = typer.Option(None, help="Chamber observations CSV (default: the bundled record of the day)."),
    theta: str = typer.Option(
        None,
        help="Leaf/light parameters: a calibration JSON or key=value,... "
        "(specular, roughness, subsurface, light_factor, vcmax_scale).",
    ),
    *,
    model: ModelOptions,
) -> None:
    """The main job: the 20 April 2016 Selhausen replication (forcing, light, photosynthesis, Fig 4)."""
    from lightfit import replication as rep
    from lightfit import weather as wx
    from lightfit.model.parameters import check_names
    from lightfit.report import field_label, summary
    from lightfit.weather.plot import plot_forcing

    s = resolve(model)
    cfg = s.replication_config()
    fld = cfg.field()  # checks boundary and buffers before anything is written
    th = parse_theta(theta)
    check_names(th, what="theta")  # before minutes of plant growth, not after
    w = weather(s)
    out.mkdir(parents=True, exist_ok=True)
    weather_report(w)
    label = str(w.attrs.get("provenance", "")).upper()
    console.print(weather_table(w, f"{label} forcing of the diurnal run ({len(w)} steps of {rep.STEP})"))
    meta = {
        "provenance": w.attrs["provenance"],
        "source": str(w.attrs.get("source")),
        "note": f"{len(w)} steps of {rep.STEP} from {rep.START_LOCAL} local ({s.how})",
    }
    wx.write_lightfit_csv(w, out / "forcing.csv", meta)
    plot_forcing(w, out / "forcing.png", title=f"{label} forcing, Selhausen 2016-04-20")
    console.print(f"running: {fld.n}×{fld.n} plants, {field_label(fld)}, K={s.samples}, {s.bounces} bounces …")
    ds, obs = rep.run(
        cfg,
        weather_file=s.weather_file,
        theta=th,
        forcing_df=w,
        observations=observations or rep.OBSERVATIONS,
        out=out,
        progress=True,
    )
    table = summary(ds)
    t = Table(
        title=f"replication summary ({label} forcing; {field_label(ds.attrs)}; "
        f"model PAR = {s.par_kind}, An per {s.an_per} area)"
    )
    # The columns are the summary's own (lightfit.report.summary), first one the local time.
    first, *numbers = table.columns
    for c in table.columns:
        t.add_column(c.replace("_umol_m2_s", "").replace("_", " "), justify="right")
    for _, r in table.iterrows():
        t.add_row(str(r[first]), *(f"{r[c]:.3g}" if np.isfinite(r[c]) else "–" for c in numbers))
    console.print(t)
    if obs is not None:
        console.print(f"observations: {obs.attrs['source']} ({obs.attrs['provenance']}, {len(obs)} row(s))")
    for f in ("forcing.csv", "forcing.png", "results.nc", "replication.png", "summary.csv"):
        console.print(f"[green]wrote[/] {out / f}")
