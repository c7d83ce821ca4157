"""The options shared by every command that runs the coupled model, and the one place that turns them into a model.

``replicate``, ``calibrate``, ``posterior`` and ``field-run`` are decorated with
:func:`model_options`: each gets the same field / light / photosynthesis / weather options (same
names, same help, same defaults) and receives them as one :class:`ModelOptions` argument.
:func:`resolve` fills what was not given from the main job's configuration
(:class:`lightfit.replication.ReplicationConfig`, or its ``quick()`` size), and
:func:`scenario` builds the :class:`~lightfit.model.scenario.Scenario` from the result.

Defaults are ``None`` here ("not given") so that ``--quick`` can change the size while an
explicit option still wins, e.g. ``--quick --samples 32``.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from lightfit.errors import InputError

_FIELD, _LIGHT, _PHOTO, _WEATHER = "Field", "Light", "Photosynthesis", "Weather"

#: Help of the field-boundary options (shared with the ``field`` command).
BOUNDARY_HELP = (
    "Field boundary: periodic (default: the measurement area is one cell of an infinite field, "
    "no buffer plants) or finite (buffer rows on bare soil; --boundary finite with its default "
    "2 buffer rows is the reference paper's setup)."
)
BUFFER_ROWS_HELP = (
    "Finite fields only: rows of unmeasured buffer plants around the measurement area "
    "(default 2, the reference paper's)."
)
BUFFER_ALONG_HELP = (
    "Finite fields only: buffer plants along each row end (default: = buffer rows; "
    "≈ 4× buffer rows makes the buffer as wide in metres both ways)."
)


@dataclass(frozen=True)
class ModelOptions:
    """The shared model options as given on the command line (``None``: not given)."""

    quick: bool = False
    n_plants: int | None = None
    boundary: str | None = None
    buffer_rows: int | None = None
    buffer_along: int | None = None
    field_seed: int | None = None
    samples: int | None = None
    bounces: int | None = None
    render_seed: int | None = None
    par_kind: str | None = None
    photosynthesis: str | None = None
    an_per: str | None = None
    weather_file: Path | None = None
    how: str | None = None
    steps: str | None = None


@dataclass(frozen=True)
class ModelSettings:
    """The resolved model options of a run: what it ran with, recorded in its outputs."""

    quick: bool
    n_plants: int
    boundary: str
    buffer_rows: int | None
    buffer_along: int | None
    field_seed: int
    samples: int
    bounces: int
    render_seed: int
    par_kind: str
    photosynthesis: str
    an_per: str
    weather_file: str | None
    how: str
    steps: str | None

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def replication_config(self):
        """The same settings as a :class:`lightfit.replication.ReplicationConfig`."""
        from lightfit.replication import ReplicationConfig

        return ReplicationConfig(
            n_plants=self.n_plants,
            boundary=self.boundary,
            buffer_rows=self.buffer_rows,
            buffer_along=self.buffer_along,
            seed=self.field_seed,
            samples=self.samples,
            bounces=self.bounces,
            render_seed=self.render_seed,
            par_kind=self.par_kind,
            an_per=self.an_per,
            how=self.how,
            photosynthesis=self.photosynthesis,
        )


# name → (type, typer option). One table, so every model command has the same options and help.
_OPTIONS: dict[str, tuple[Any, Any]] = {
    "quick": (
        bool,
        typer.Option(
            "--quick",
            help="First look in under a minute (the CI size): 4 plants, K=16, 2 bounces; explicit options still win.",
            rich_help_panel=_FIELD,
        ),
    ),
    "n_plants": (
        int | None,
        typer.Option(
            "--n-plants",
            help="Plants in the measurement area, rounded up to a square N×N (default 100; --quick: 4).",
            rich_help_panel=_FIELD,
        ),
    ),
    "boundary": (
        str | None,
        typer.Option(
            "--boundary",
            help=BOUNDARY_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "buffer_rows": (
        int | None,
        typer.Option(
            "--buffer-rows",
            help=BUFFER_ROWS_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "buffer_along": (
        int | None,
        typer.Option(
            "--buffer-along",
            help=BUFFER_ALONG_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "field_seed": (
        int | None,
        typer.Option(
            "--field-seed",
            help="Field seed: plant seeds derive from it and each plant's grid position (default 1).",
            rich_help_panel=_FIELD,
        ),
    ),
    "samples": (
        int | None,
        typer.Option(
            "--samples", help="Irradiance samples per segment K (default 64; --quick: 16).", rich_help_panel=_LIGHT
        ),
    ),
    "bounces": (
        int | None,
        typer.Option("--bounces", help="Scattering orders (default 3; --quick: 2).", rich_help_panel=_LIGHT),
    ),
    "render_seed": (
        int | None,
        typer.Option(
            "--render-seed",
            help="Seed of the irradiance sample streams (common random numbers; default 0).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "par_kind": (
        str | None,
        typer.Option(
            "--par-kind", help="PAR observable: incident or absorbed (default absorbed).", rich_help_panel=_LIGHT
        ),
    ),
    "photosynthesis": (
        str | None,
        typer.Option(
            "--photosynthesis",
            help="Photosynthesis parameter set: winter_wheat, cplantbox, giraud2023 or giraud2023_coupled "
            "(default: the main job's, lightfit.model.scenario.Scenario.photosynthesis; docs/photosynthesis.md).",
            rich_help_panel=_PHOTO,
        ),
    ),
    "an_per": (
        str | None,
        typer.Option(
            "--an-per",
            help="Canopy net CO2 uptake per ground or leaf area (default ground).",
            rich_help_panel=_PHOTO,
        ),
    ),
    "weather_file": (
        Path | None,
        typer.Option(
            "--weather",
            help="A real TERENO export (or other weather file) instead of the bundled reconstructed "
            "forcing of 2016-04-20.",
            rich_help_panel=_WEATHER,
        ),
    ),
    "how": (
        str | None,
        typer.Option(
            "--how",
            help="30-min steps from finer data: sample (as the reference paper) or mean (default sample).",
            rich_help_panel=_WEATHER,
        ),
    ),
    "steps": (
        str | None,
        typer.Option(
            "--steps",
            help="Time steps to run: a count from 05:00 local (e.g. 5) or positions a:b (default: all 29).",
            rich_help_panel=_WEATHER,
        ),
    ),
}
assert set(_OPTIONS) == {f.name for f in dataclasses.fields(ModelOptions)}


#: ``--use`` of the commands that compare the model with observations (calibrate, posterior).
Use = Annotated[str, typer.Option("--use", help="Observed series in the likelihood: par, an or par,an.")]


def model_options(func: Callable[..., Any]) -> Callable[..., Any]:
    """Give a command the shared model options; it receives them as its ``model: ModelOptions`` argument.

    Typer reads a command's options from its signature, so the wrapper's signature is the
    command's own parameters (without ``model``) followed by the shared ones.
    """
    own = [p for p in inspect.signature(func, eval_str=True).parameters.values() if p.name != "model"]
    shared = [
        inspect.Parameter(
            name,
            inspect.Parameter.KEYWORD_ONLY,
            default=False if name == "quick" else None,
            annotation=Annotated[typ, opt],
        )
        for name, (typ, opt) in _OPTIONS.items()
    ]

    def command(**kwargs: Any) -> Any:
        model = ModelOptions(**{name: kwargs.pop(name) for name in _OPTIONS})
        return func(model=model, **kwargs)

    command.__name__, command.__qualname__, command.__doc__ = func.__name__, func.__qualname__, func.__doc__
    command.__module__ = func.__module__
    params = own + shared
    command.__signature__ = inspect.Signature(params)
    command.__annotations__ = {p.name: p.annotation for p in params}
    return command


def resolve(opts: ModelOptions) -> ModelSettings:
    """Fill the options not given from the main job's configuration (or its ``--quick`` size)."""
    from lightfit.photosynthesis import PARAMETER_SET_NAMES
    from lightfit.replication import ReplicationConfig

    base = ReplicationConfig.quick() if opts.quick else ReplicationConfig()

    def given(value, default):
        return default if value is None else value

    boundary = given(opts.boundary, base.boundary)
    buffers = check_boundary(boundary, opts.buffer_rows, opts.buffer_along)
    s = ModelSettings(
        quick=opts.quick,
        n_plants=given(opts.n_plants, base.n_plants),
        boundary=boundary,
        buffer_rows=buffers[0],
        buffer_along=buffers[1],
        field_seed=given(opts.field_seed, base.seed),
        samples=given(opts.samples, base.samples),
        bounces=given(opts.bounces, base.bounces),
        render_seed=given(opts.render_seed, base.render_seed),
        par_kind=given(opts.par_kind, base.par_kind),
        photosynthesis=given(opts.photosynthesis, base.photosynthesis),
        an_per=given(opts.an_per, base.an_per),
        weather_file=None if opts.weather_file is None else str(opts.weather_file),
        how=given(opts.how, base.how),
        steps=opts.steps,
    )
    # Checked here (not only deep inside the run) so that a typo fails before minutes of plant growth.
    if s.photosynthesis not in PARAMETER_SET_NAMES:
        raise InputError(
            f"photosynthesis={s.photosynthesis!r}", column="photosynthesis", expected=" or ".join(PARAMETER_SET_NAMES)
        )
    if s.how not in ("sample", "mean"):
        raise InputError(f"how={s.how!r}", column="how", expected="'sample' or 'mean'")
    return s


#: Settings that change what the model renders: a cached emulator is valid only for the same values.
RENDER_SETTINGS = (
    "n_plants",
    "boundary",
    "buffer_rows",
    "buffer_along",
    "field_seed",
    "samples",
    "bounces",
    "render_seed",
    "weather_file",
    "how",
    "steps",
)
#: Settings that change the model's outputs: a resumed calibration or posterior needs the same values.
MODEL_SETTINGS = (*RENDER_SETTINGS, "par_kind", "photosynthesis", "an_per")


def changed_settings(previous: dict | None, s: ModelSettings, keys=MODEL_SETTINGS) -> list[str]:
    """``"key: before → now"`` for each of ``keys`` that differs between a stored run's settings
    (its ``config``) and ``s``. Settings written before the periodic boundary have no
    ``boundary``: they were finite fields. ``previous=None`` (nothing stored): no difference.
    """
    if previous is None:
        return []
    now = s.as_dict()
    before = {"boundary": "finite"} | dict(previous)
    return [f"{k}: {before.get(k)!r} → {now[k]!r}" for k in keys if before.get(k) != now[k]]


def check_resumable(previous: dict | None, s: ModelSettings, file, what: str) -> None:
    """Refuse to resume a run stored with other model settings (it would mix two models)."""
    diff = changed_settings(previous, s)
    if diff:
        raise InputError(
            f"the {what} there was made with other model settings ({'; '.join(diff)})",
            file=file,
            expected="the same settings as that run, --no-resume to start again, or another --out",
        )


def check_boundary(boundary: str, buffer_rows: int | None, buffer_along: int | None) -> tuple[int | None, int | None]:
    """``--boundary`` with the buffers given: (buffer_rows, buffer_along) of the field.

    Periodic: no buffers (``(None, None)``); ``--buffer-rows`` / ``--buffer-along`` given
    explicitly are an error naming them (a periodic field's neighbours are its own copies).
    Finite: the buffers as given; ``None`` rows → 2 (the reference paper's), ``None`` along → rows.
    """
    from lightfit.plant.field import BOUNDARIES, DEFAULT_BUFFER_ROWS

    if boundary not in BOUNDARIES:
        raise InputError(f"boundary={boundary!r}", column="boundary", expected=" or ".join(BOUNDARIES))
    if boundary == "periodic":
        given = [f"--{n}" for n, v in (("buffer-rows", buffer_rows), ("buffer-along", buffer_along)) if v is not None]
        if given:
            raise InputError(
                f"{' and '.join(given)} given with --boundary periodic",
                column="boundary",
                expected="no buffer options with a periodic field (its neighbours are its own copies), "
                "or --boundary finite",
            )
        return None, None
    return (DEFAULT_BUFFER_ROWS if buffer_rows is None else buffer_rows), buffer_along


def weather(s: ModelSettings):
    """The run's forcing: 30-min steps of 2016-04-20 05:00–19:00 local, or the ``--steps`` of them."""
    from lightfit.replication import forcing

    if s.weather_file is not None and not Path(s.weather_file).is_file():
        raise InputError("no such file", file=s.weather_file, expected="a weather file (--weather)")
    w = forcing(s.weather_file, s.how)
    return w.iloc[_steps(s.steps, len(w))] if s.steps else w


def scenario(s: ModelSettings, w=None):
    """The :class:`~lightfit.model.scenario.Scenario` of the settings (``w``: the forcing if already read)."""
    from lightfit.replication import scenario_for

    return scenario_for(s.replication_config(), weather(s) if w is None else w)


def coupled_model(s: ModelSettings, w=None, progress: bool = True):
    """The :class:`~lightfit.model.coupled.CoupledModel` of the settings (grows the plants, builds the scene)."""
    from lightfit.model.coupled import CoupledModel

    return CoupledModel(scenario(s, w), progress=progress)


def _steps(text: str, n: int) -> slice:
    """``"5"`` → the first 5 steps; ``"a:b"`` → positions a to b (Python slice, either end optional)."""
    try:
        if ":" in text:
            a, _, b = text.partition(":")
            sl = slice(int(a) if a else None, int(b) if b else None)
            if not range(n)[sl]:
                raise ValueError
            return sl
        k = int(text)
        if not 1 <= k <= n:
            raise ValueError
        return slice(0, k)
    except ValueError:
        raise InputError(f"steps={text!r}", column="steps", expected=f"a count 1…{n} or positions a:b") from None
