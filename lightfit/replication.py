"""The 20 April 2016 Selhausen replication: the main job.

CPlantBox wheat grown from 2016-03-05 to 2016-04-20, a 10 × 10-plant measurement area as one
cell of an infinite periodic field (default; ``boundary="finite"`` with two buffer rows is the
reference paper's setup), the day's forcing (bundled reconstruction unless a real TERENO export is given),
05:00–19:00 local time in 30-minute steps (29 steps), light and photosynthesis per segment.
Outputs: results netCDF (time × segment), a Fig-4-like PNG (PAR with its spread across
segments, canopy net CO2 uptake, observations where present), the forcing, and a summary table.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit import weather
from lightfit.errors import InputError
from lightfit.inference.observations import align, read_observations
from lightfit.light.leaf_optics import DEFAULT_PRESET, LeafTraits
from lightfit.light.leaf_optics import PRESETS as LEAF_PRESETS
from lightfit.light.scene import Optics
from lightfit.model import schema
from lightfit.model.coupled import CoupledModel
from lightfit.model.parameters import Theta, as_theta
from lightfit.model.scenario import Scenario
from lightfit.plant import Field
from lightfit.report import plot, summary
from lightfit.weather.bundled import DATA_DIR

START_LOCAL = "2016-04-20 05:00"
HOURS, STEP = 14.0, "30min"
OBSERVATIONS = DATA_DIR / "observations" / "chamber_2016-04-20_record.csv"


@dataclass(frozen=True)
class ReplicationConfig:
    """Knobs of the replication; ``quick()`` is the under-a-minute first look (and the CI size).

    ``boundary``: ``"periodic"`` (default: the measurement area is one cell of an infinite field,
    no buffer plants; docs/light.md, "Periodic boundary") or ``"finite"`` (buffer rows on bare
    soil; with ``buffer_rows=None`` → 2, the reference paper's setup). ``buffer_rows`` /
    ``buffer_along``: ``None`` means the boundary's default (2 finite, 0 periodic); explicit
    non-zero buffers with a periodic boundary are refused (:class:`lightfit.plant.Field`).

    ``optics``: leaf optics preset, ``"prospect"`` (default: PROSPECT-D wheat leaf, PAR absorptance
    0.90) or ``"paper"`` (the reference paper's grey 0.5 leaf); ``chlorophyll_ug_cm2``: leaf
    chlorophyll a+b of the ``prospect`` leaf (``None``: the default trait, 50.5 µg cm⁻²; prior range
    :data:`lightfit.light.leaf_optics.CHLOROPHYLL_PRIOR_UG_CM2`). Named presets of the whole model
    setup: :data:`PAPER_PRESET` via :meth:`paper` / :meth:`with_preset` (docs/model.md, "Presets").
    """

    n_plants: int = 100
    boundary: str = "periodic"
    buffer_rows: int | None = None
    buffer_along: int | None = None
    seed: int = 1
    samples: int = 64
    bounces: int = 3
    render_seed: int = 0
    par_kind: str = "absorbed"
    an_per: str = "ground"
    how: str = "sample"
    photosynthesis: str = Scenario.photosynthesis
    optics: str = DEFAULT_PRESET
    chlorophyll_ug_cm2: float | None = None

    @staticmethod
    def quick() -> ReplicationConfig:
        return ReplicationConfig(n_plants=4, samples=16, bounces=2)

    @staticmethod
    def paper() -> ReplicationConfig:
        """The reference paper's whole setup at the main job's size (:data:`PAPER_PRESET`)."""
        return ReplicationConfig().with_preset("paper")

    def with_preset(self, name: str) -> ReplicationConfig:
        """This configuration with the model choices of a named preset (:data:`PRESETS`): ``"default"``
        (lightfit's credible default: the class defaults) or ``"paper"`` (:data:`PAPER_PRESET`). The
        run's size (plants, samples, bounces, seeds) is kept: ``quick().with_preset("paper")`` is the
        paper's setup at the CI size."""
        if name == "paper":
            return replace(self, **PAPER_PRESET)
        if name == "default":
            base = ReplicationConfig()
            return replace(self, **{k: getattr(base, k) for k in PAPER_PRESET})
        raise InputError(f"preset={name!r}", column="preset", expected=" or ".join(PRESETS))

    def leaf_optics(self) -> Optics:
        """The run's :class:`~lightfit.light.scene.Optics` (checks the preset and the chlorophyll)."""
        if self.optics not in LEAF_PRESETS:
            raise InputError(f"optics={self.optics!r}", column="optics", expected=" or ".join(LEAF_PRESETS))
        if self.chlorophyll_ug_cm2 is None:
            return Optics.preset(self.optics)
        if self.optics != "prospect":
            raise InputError(
                f"chlorophyll_ug_cm2={self.chlorophyll_ug_cm2!r} with optics {self.optics!r}",
                column="chlorophyll_ug_cm2",
                expected="optics 'prospect' (the paper's grey leaf is not made from leaf traits)",
            )
        try:
            return Optics.from_traits(LeafTraits(Cab=self.chlorophyll_ug_cm2))
        except InputError as e:
            raise InputError(
                f"chlorophyll_ug_cm2={self.chlorophyll_ug_cm2!r}", column="chlorophyll_ug_cm2", expected=e.expected
            ) from None

    def finite(self, buffer_rows: int = 2, buffer_along: int | None = None) -> ReplicationConfig:
        """The same run on a finite field; the defaults are the reference paper's 2 buffer rows."""
        return replace(self, boundary="finite", buffer_rows=buffer_rows, buffer_along=buffer_along)

    def field(self) -> Field:
        """The run's :class:`~lightfit.plant.Field` (checks boundary and buffers)."""
        return Field(
            n_plants=self.n_plants,
            buffer_rows=self.buffer_rows,
            seed=self.seed,
            buffer_along=self.buffer_along,
            boundary=self.boundary,
        )


#: The reference paper's setup (Baker et al. 2025): a finite field with 2 buffer rows on bare soil,
#: the grey 0.5 leaf, the giraud2023 photosynthesis set and, as PAR at the plants, the area-mean
#: absorbed PAR of all leaf segments. ``replication_quick_finite.json`` is its regression curve.
PAPER_PRESET = {
    "boundary": "finite",
    "buffer_rows": 2,
    "buffer_along": None,
    "optics": "paper",
    "chlorophyll_ug_cm2": None,
    "photosynthesis": "giraud2023",
    "par_kind": "absorbed",
}
#: Named presets of :meth:`ReplicationConfig.with_preset`; ``default`` is the class defaults.
PRESETS = ("default", "paper")


def forcing(weather_file: str | Path | None = None, how: str = "sample") -> pd.DataFrame:
    """The run's 29 steps: bundled reconstruction, or the given weather file, with solar columns."""
    src = (
        weather.read_weather(weather_file) if weather_file else weather.read_weather(weather.bundled_path("2016-04-20"))
    )
    src = weather.add_solar(src)
    return weather.window(src, START_LOCAL, HOURS, STEP, how=how)


def scenario_for(cfg: ReplicationConfig, w: pd.DataFrame) -> Scenario:
    """The :class:`Scenario` of a configuration over the forcing ``w`` (the one place that maps one to the other)."""
    return Scenario(
        weather=w,
        field=cfg.field(),
        samples=cfg.samples,
        bounces=cfg.bounces,
        seed=cfg.render_seed,
        par_kind=cfg.par_kind,
        an_per=cfg.an_per,
        photosynthesis=cfg.photosynthesis,
        optics=cfg.leaf_optics(),
    )


def model_for(cfg: ReplicationConfig, w: pd.DataFrame, progress: bool = False) -> CoupledModel:
    return CoupledModel(scenario_for(cfg, w), progress=progress)


def run(
    cfg: ReplicationConfig,
    *,
    weather_file=None,
    theta: Theta | dict | None = None,
    observations=OBSERVATIONS,
    out: Path | None = None,
    progress: bool = False,
    forcing_df: pd.DataFrame | None = None,
):
    """Run the replication; write outputs to ``out`` if given. Returns (Dataset, observations or None).

    ``forcing_df``: the run's forcing if already read (``forcing(weather_file, cfg.how)``).
    """
    w = forcing(weather_file, cfg.how) if forcing_df is None else forcing_df
    model = model_for(cfg, w, progress)
    ds = model.simulate(as_theta(theta, model.scenario.theta))  # leaf defaults: the run's optics
    ds.attrs["replication_config"] = json.dumps(asdict(cfg))
    obs = read_observations(observations) if observations else None
    if obs is not None:
        a = align(obs, model.times)
        for k, v in a.items():
            ds[f"obs_{k}"] = ("time", v)
        schema.annotate(ds)
        ds.attrs["observations"] = f"{obs.attrs['source']} ({obs.attrs['provenance']})"
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_netcdf(ds, out / "results.nc")
        plot(ds, out / "replication.png")
        summary(ds).to_csv(out / "summary.csv", float_format="%.4g")
    return ds, obs


def write_netcdf(ds, path: Path) -> Path:
    """netCDF4 via h5netcdf (booleans stored as int8)."""
    ds = ds.copy()
    for v in list(ds.variables):
        if ds[v].dtype == bool:
            ds[v] = ds[v].astype(np.int8)
    ds.to_netcdf(path, engine="h5netcdf")
    return path
