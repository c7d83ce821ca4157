"""Gallery figure: a few images with their labels side by side (after the reference paper's Fig. 3).

Columns: the tone-mapped image, segment ids (one colour per segment), absorbed PAR, and the
limitation margin (Vj − Vc)/(Vj + Vc) on a divergent red/blue scale centred on 0 — red where
Fj > Fc (Rubisco limited), blue where Fj < Fc (electron-transport limited) — or, when Vc/Vj are
not in the results, the first other quantity. A class map (``limitation``) is drawn in one colour
per class (red Rubisco limited, blue electron-transport limited, as on the margin's scale), its
colour bar naming the classes. Pixels without a value (NaN, or a class map's −1) show the panel's
dark background.

The figure's title says what it shows (data honesty): the results file and whether its values are a
model run or synthetic, the provenance of the forcing the run was driven by and of the sun and sky
that lit the images (:func:`lightfit.weather.plot.provenance_label`), and the site's local date and
time zone; each row gives its image's local time (the file names carry UTC).
"""

from __future__ import annotations

from pathlib import Path
from textwrap import fill

import numpy as np

from lightfit.dataset.labels import NO_CLASS
from lightfit.dataset.results import MARGIN, QUANTITIES
from lightfit.figure import date_span, unit_label

PREFERRED = ("absorbed_par", MARGIN)


def segment_colours(segment_id: np.ndarray) -> np.ndarray:
    """(H, W, 3) float colours: a fixed pseudo-random colour per segment id, black for background."""
    h = (segment_id.astype(np.uint64) * np.uint64(2654435761)) % np.uint64(2**24)
    rgb = np.stack([(h >> np.uint64(s)) & np.uint64(255) for s in (0, 8, 16)], axis=-1).astype(float) / 255.0
    rgb = 0.25 + 0.75 * rgb  # never as dark as the background
    rgb[segment_id < 0] = 0.0
    return rgb


def quantity_title(name: str) -> str:
    """A label panel's title: the quantity's ``long_name`` in the results schema (``absorbed_par``:
    "PAR absorbed by the segment"), with a class map's codes (``limitation``: 0 Rubisco limited,
    1 electron transport limited; its −1, no value, is not drawn); the name itself outside the schema."""
    from lightfit.model import schema

    var = schema.VARIABLES.get(QUANTITIES.get(name, name))
    if var is None:
        return name
    codes = [f"{c} {m}" for c, m in class_codes(name)]
    return var.long_name + ("\n" + ", ".join(codes) if codes else "")


#: A class map's colours by code: 0 red, 1 blue, so that ``limitation``'s Rubisco-limited class is
#: red and its electron-transport-limited class blue, as on the margin's divergent scale.
CLASS_COLOURS = ("#d6604d", "#4393c3", "#7fbf7b", "#c2a5cf")


def class_codes(name: str) -> list[tuple[int, str]]:
    """A class map's codes and their meanings from the results schema's flags (``limitation``:
    ``[(0, "Rubisco limited"), (1, "electron transport limited")]``), without the −1 "no value"
    code (not drawn); ``[]`` for a quantity that is not a class map."""
    from lightfit.model import schema

    var = schema.VARIABLES.get(QUANTITIES.get(name, name))
    if var is None or not var.flags:
        return []
    pairs = [f.split(" ", 1) for f in var.flags.split(", ")]
    return [(int(v), m) for v, m in pairs if int(v) != NO_CLASS]


def _columns(quantities: list[str]) -> list[str]:
    cols = [q for q in PREFERRED if q in quantities]
    if MARGIN not in cols:
        cols += [q for q in quantities if q not in cols][: 2 - len(cols)]
    return cols


def gallery_title(res, lighting: dict | None = None, times_utc=()) -> str:
    """The gallery's title, from a :class:`~lightfit.dataset.results.Results` ``res``: the results'
    source and what its values are, the run's forcing provenance, the provenance of the images'
    sun and sky (``lighting``: :func:`~lightfit.dataset.results.lighting_provenance`), and the
    site's local date(s) of ``times_utc`` (aware instants) with its time zone."""
    import pandas as pd

    from lightfit.dataset.results import _site, synthetic_values
    from lightfit.weather.plot import provenance_label, source_names
    from lightfit.weather.site import zone_label

    a = res.ds.attrs
    source = Path(res.path).name if res.path else "results given in memory"
    line = f"Labels from {source}: " + ("SYNTHETIC values (not a model run)" if synthetic_values(a) else "model output")
    if not synthetic_values(a) or "weather_provenance" in a:  # a synthetic file was driven by no forcing
        wx = source_names(a)
        line += f"; {provenance_label(a, 'weather_provenance', 'weather_date_given')} forcing" + (
            f" ({wx})" if wx else ""
        )
    lines = [line]
    if lighting and lighting.get("from") == "weather":  # not the run's own sun and sky: another series lit them
        lit = provenance_label(lighting, "provenance", "placed_on_date")
        lines.append(f"images lit by {lit} weather ({Path(str(lighting.get('source'))).name})")
    elif lighting:
        lines.append("images lit by the results' own sun and sky")
    site = _site(res)
    local = pd.DatetimeIndex(list(times_utc)).tz_convert(site.timezone)
    day = date_span(local)
    lines.append(f"{site.name}, {day}, local time ({zone_label(site.timezone)}); file names in UTC (Z)")
    return "\n".join(lines)


def gallery(
    out_dir: Path,
    images: list[dict],
    quantities: list[str],
    units: dict[str, str] | None = None,
    *,
    results=None,
    lighting: dict | None = None,
) -> Path:
    """Write ``gallery.png`` in ``out_dir`` for the image entries of the metadata; return its path.
    ``units``: each quantity's units, written on its colour bar. ``results``: the
    :class:`~lightfit.dataset.results.Results` the labels come from, for the title
    (:func:`gallery_title`, with ``lighting``) and each image's local time."""
    import pandas as pd

    units = units or {}
    times = [pd.Timestamp(e["time_utc"]) for e in images]
    title, tz = None, None
    if results is not None:
        from lightfit.dataset.results import _site

        title, tz = gallery_title(results, lighting, times), _site(results).timezone
    # The object API needs no pyplot backend: safe in any process (tests, notebooks, servers).
    from matplotlib.colors import BoundaryNorm, ListedColormap, TwoSlopeNorm
    from matplotlib.figure import Figure
    from PIL import Image

    cols = _columns(quantities)
    n = len(images)
    fig = Figure(figsize=(3.2 * (2 + len(cols)), 3.0 * n))
    axes = fig.subplots(n, 2 + len(cols), squeeze=False)
    for r, entry in enumerate(images):
        png = np.asarray(Image.open(out_dir / entry["png"]))
        with np.load(out_dir / entry["labels"]) as z:
            labels = {k: z[k] for k in z.files}
        ax = axes[r]
        ax[0].imshow(png, cmap="gray" if png.ndim == 2 else None, vmin=0, vmax=255)
        clip = entry["exposure"]["clipped_leaf_fraction"]
        head = entry["name"]
        if tz is not None:  # the site's clock: the name's time is UTC
            head += f"\n{times[r].tz_convert(tz):%Y-%m-%d %H:%M} local time"
        ax[0].set_title(head + (f"\nclipped leaf px {clip:.1%}" if clip is not None else ""), fontsize=8)
        ax[1].imshow(segment_colours(labels["segment_id"]))
        ax[1].set_title("segment id", fontsize=8)
        for j, q in enumerate(cols):
            a = ax[2 + j]
            v = np.ma.masked_invalid(labels[q].astype(float))
            is_class_map = labels[q].dtype.kind in "iu"
            if is_class_map:  # its "no value" code is no class (was painted as one)
                v = np.ma.masked_where(labels[q] == NO_CLASS, v)
            # a class map's (code, meaning); the margin has its own scale
            codes = class_codes(q) if is_class_map and q != MARGIN else []
            if q == MARGIN:
                lim = float(np.nanmax(np.abs(v))) if v.count() else 1.0
                im = a.imshow(v, cmap="RdBu_r", norm=TwoSlopeNorm(0.0, -lim or -1.0, lim or 1.0))
                a.set_title(
                    "(Vj−Vc)/(Vj+Vc): red Fj>Fc, Rubisco limited;\nblue Fj<Fc, electron-transport limited", fontsize=8
                )
            elif codes:  # classes: one colour each, named on the bar
                values = [c for c, _ in codes]
                edges = [values[0] - 0.5, *(c + 0.5 for c in values)]
                im = a.imshow(
                    v,
                    cmap=ListedColormap(CLASS_COLOURS[: len(codes)]),
                    norm=BoundaryNorm(edges, len(codes)),
                    interpolation="nearest",
                )
                a.set_title(quantity_title(q), fontsize=8)
            else:
                im = a.imshow(v, cmap="viridis")
                a.set_title(quantity_title(q), fontsize=8)
            a.set_facecolor("0.15")
            bar = fig.colorbar(im, ax=a, fraction=0.046, pad=0.02)
            if codes:  # named classes, no unit
                bar.set_ticks([c for c, _ in codes])
                bar.set_ticklabels([fill(m, 12) for _, m in codes], fontsize=7)
                bar.minorticks_off()
            elif units.get(q):  # a ratio's CF unit "1" read as a number on the bar; the others in the figures' style
                bar.set_label(unit_label(units[q]), fontsize=7)
        for a in ax:
            a.set_xticks([])
            a.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = Path(out_dir) / "gallery.png"
    fig.savefig(path, dpi=100)
    return path
