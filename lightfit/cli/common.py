"""What every command shares: the consoles, the one error handler, parameter and weather-table helpers."""

from __future__ import annotations

import atexit
import json
import logging
import math
import os
import sys
import warnings
from pathlib import Path
from typing import NoReturn

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from typer.core import TyperCommand, TyperGroup

from lightfit.cache import ENV_CACHE, cache_root
from lightfit.errors import InputError
from lightfit.killpoint import interrupts_kept

#: Results and tables go to stdout; errors go to stderr (so that piped output stays clean).
console = Console()
err_console = Console(stderr=True)


def _user_errors() -> tuple[type[BaseException], ...]:
    """Exceptions that mean "the input is wrong", not "lightfit is broken" (those keep their traceback)."""
    from lightfit.light.backend import BackendError

    # TimeoutError: a limit the user set ran out (field-run --timeout / --connect-timeout).
    return (
        InputError,
        BackendError,
        FileNotFoundError,
        FileExistsError,  # a folder to create where a file is (--out afile/x)
        IsADirectoryError,
        NotADirectoryError,
        PermissionError,
        TimeoutError,
    )


def _flags_without_type(command, ctx) -> None:
    """Typer 0.29's help shows a flag as ``--quick <bool>``, which reads as an option taking a value
    (``--quick true`` is then a usage error): a flag's type column is left empty, in ``command`` and the
    commands of a group below it."""
    sub = type(command).context_class(command, info_name=command.name, parent=ctx)
    _no_type_for_flags(command.get_params(sub))
    for name in getattr(command, "commands", {}):
        _flags_without_type(command.commands[name], sub)


def _no_type_for_flags(params) -> None:
    for p in params:
        if getattr(p, "is_flag", False) and p.metavar is None:
            p.metavar = ""


class LightfitGroup(TyperGroup):
    """The app's command group, with the one error handler of the command line.

    Expected user errors raised anywhere below it (any command, the weather sub-app, the
    callback) print ``error: <message>`` on stderr and exit with status 2 — no traceback.
    Usage errors (unknown option, missing argument) are typer's, also on stderr with status 2.
    """

    def get_params(self, ctx):
        params = super().get_params(ctx)
        _no_type_for_flags(params)
        return params

    def get_command(self, ctx, cmd_name):
        command = super().get_command(ctx, cmd_name)
        if command is not None:
            _flags_without_type(command, ctx)
        return command

    def invoke(self, ctx):
        command, args = invoked_command(self, ctx), invoked_args(ctx)  # click clears them when invoking

        def stop() -> NoReturn:
            name = getattr(command, "name", None)
            kept = RESUMABLE.get(f"{name} --no-surrogate" if "--no-surrogate" in args else name, RESUMABLE.get(name))
            interrupted(kept, "--no-resume" in args)

        try:
            with warnings.catch_warnings(), interrupts_kept():
                warnings.showwarning = _show_warning
                return super().invoke(ctx)
        except _user_errors() as err:
            msg = " ".join(error_message(err, option_flags(command)).splitlines())  # one line
            # soft_wrap: a long file path must stay on one line, for users and for tests alike.
            err_console.print(f"[bold red]error:[/] {escape(msg)}", soft_wrap=True, highlight=False)
            raise typer.Exit(2) from None
        except KeyboardInterrupt:  # Ctrl-C
            stop()
        except Exception as err:
            # Ctrl-C inside a JAX host callback (a render) reaches here as the callback's error,
            # which printed some 60 lines of traceback: a JaxRuntimeError from a traced loss, a
            # ValueError of the same text from `replicate`'s eager call (a real SIGINT, jax 0.10).
            text = str(err)
            if isinstance(err, (RuntimeError, ValueError)) and "CpuCallback" in text and "KeyboardInterrupt" in text:
                stop()
            raise


class LightfitCommand(TyperCommand):
    """A command of the app, which sets lightfit's JAX policy (:mod:`lightfit.precision`) just
    before it runs. Not in the app's callback: click runs that before the command reads its
    arguments, so ``--help`` and a usage error waited for JAX to import."""

    def invoke(self, ctx):
        from lightfit.precision import use_compilation_cache, use_float64

        # Before the command creates a JAX array: lightfit computes in float64 only (lightfit.precision).
        use_float64()
        use_compilation_cache()
        return super().invoke(ctx)


#: Exit status of an interrupted command: 128 + SIGINT, as shells report it.
INTERRUPTED = 130

#: Exit status of a ``calibrate`` whose surrogate optimum the full renders did not confirm (its
#: trust region's check did not pass): the result is written, but is not an answer. Distinct from 2
#: (bad input, usage errors), 1 (an uncaught error: a bug) and 130 (interrupted).
CHECK_NOT_PASSED = 3


def interrupted(kept: str | None, started_over: bool = False) -> NoReturn:
    """Ctrl-C's one line on stderr — what was kept (``None``: nothing to resume from) and how to
    go on — and exit status :data:`INTERRUPTED`. ``started_over``: the run
    was started with ``--no-resume``, which its rerun would repeat."""
    if kept is None:
        line = "rerun the command to start it again"
    else:
        line = f"{kept}; rerun {'without --no-resume' if started_over else 'the same command'} to resume"
    err_console.print(f"[yellow]interrupted[/]: {line}", soft_wrap=True, highlight=False)
    # The line above is the last word: cleanup at exit that fails or warns because the run was cut
    # short (Dask's atexit close of a cluster interrupted while it started asserted "Status.init", 30
    # lines of traceback after this line, or logged a worker's exit code) is not reported. Registered
    # last, this runs before the other exit handlers; the process itself is not changed before exit
    # (tests call commands in one process).
    atexit.unregister(_quiet_exit)
    atexit.register(_quiet_exit)
    raise typer.Exit(INTERRUPTED)


def _quiet_exit() -> None:
    sys.unraisablehook = lambda unraisable: None
    logging.disable(logging.CRITICAL)


#: What a command interrupted anywhere keeps for its rerun (tests/test_resume.py kills them at
#: every stage and reruns them to the uninterrupted result). ``posterior`` interrupted while
#: sampling says so itself, with the chain's status.
RESUMABLE = {
    "posterior": "every finished design render is kept in the design cache and every finished "
    "sampling step in --out's run.h5",
    "calibrate": "every finished design render is kept in the design cache; a rerun redoes the fits "
    "and optimisations on the surrogate from them (seconds) without rendering again",
    "calibrate --no-surrogate": "every accepted step is kept in --out's history.jsonl",
    "field-run": "every finished task is kept beside --out (OUT.parts/)",
    "replicate": "every rendered step is kept in --out (its .kept-steps folder)",
    "render-dataset": "every rendered camera is kept in --out (its .unfinished folder)",
}


def invoked_args(ctx) -> list[str]:
    """The command line's arguments after the program's name, as the group's context holds them."""
    return [*(getattr(ctx, "_protected_args", None) or getattr(ctx, "protected_args", None) or []), *ctx.args]


def invoked_command(group, ctx):
    """The (sub-)command that the group's arguments name, e.g. ``weather show``; the group itself
    when they name none."""
    command = group
    for a in invoked_args(ctx):
        sub = getattr(command, "commands", {}).get(a)  # a group's commands (typer vendors click)
        if sub is None:
            break
        command = sub
    return command


#: Library parameter names whose command-line option is spelled otherwise: the first of the
#: candidates that the invoked command has.
OPTION_ALIASES = {
    "freq": ("--step", "--resample"),
    "names": ("--parameters",),
    "nwalkers": ("--walkers",),
    "seed": ("--field-seed",),
    "width_px": ("--width",),
    "distance_m": ("--sweep-distance-m",),
    "quantities": ("--quantity",),
    "times": ("--time",),
    "plant_spacing_m": ("--plant-spacing",),
    "row_spacing_m": ("--row-spacing",),
    "split_model": ("--split",),
    "format": ("--format",),
    "n": ("--sweep",),
    "gallery_images": ("--gallery",),
    "elevation_deg": ("--sweep-elevation-deg",),
    "height_px": ("--height",),
    "n_tiles": ("--tiles",),
    "target_date": ("--date",),
    "soil_respiration_umol_m2_s": ("--soil-respiration",),
    "photosynthesis_overrides": ("--photosynthesis-override",),  # a value outside its domain (with_overrides)
    "row_direction_deg": ("--row-direction",),
    "season_start": ("--season-start",),
    "date": ("--date",),
    "provenance": ("--provenance", "--weather-provenance"),
    "window.start": ("--start-time",),  # not "start": calibrate's --start is its first θ
}


#: Parameters that, named in an error about a file (without a line), are the option applied to it:
#: ``--tz`` on a lightfit CSV, ``--provenance`` contradicting the file, ``--date`` placing an undated
#: file, ``--growth-temperature-c series`` reading its month before. Others (a ``time_label``
#: metadata line) are the file's own.
FILE_OPTIONS = {
    "tz",
    "provenance",
    "format",
    "out",
    "start_time",
    "use",
    "theta",
    "start",
    "freq",
    "date",
    "growth_temperature_c",
}


def option_flags(command) -> dict[str, str]:
    """The options of one command by parameter name (``n_plants`` → ``--n-plants``), and the
    :data:`OPTION_ALIASES` it has: an error names only an option that the user could have given."""
    flags = {}
    for p in command.params:
        long = [o for o in getattr(p, "opts", ()) if o.startswith("--")]
        if long and p.name:
            flags[p.name] = long[0]
    have = set(flags.values())
    for name, candidates in OPTION_ALIASES.items():
        found = [c for c in candidates if c in have]
        if found and name not in flags:
            flags[name] = found[0]
    return flags


def error_message(err: BaseException, flags: dict[str, str] | None = None) -> str:
    """One line naming the file or parameter concerned (``InputError`` messages already do). An
    :class:`InputError` about a parameter that is an option of the invoked command (``flags``:
    :func:`option_flags`; no file, or a file but no line: the option as applied to that file) names
    the option: ``option --preset: …``, not ``column 'preset'``."""
    column = err.column.lstrip("-").replace("-", "_") if isinstance(err, InputError) and err.column else None
    if column and flags and (err.file is None or (err.row is None and column in FILE_OPTIONS)):
        flag = flags.get(column)
        if flag is not None:  # a file's error without a line is about the option used on it (--tz on a CSV)
            where = f"option {flag}" + (f", line {err.row}" if err.row is not None else "")
            where = where if err.file is None else f"{err.file}: {where}"
            return f"{where}: {err.problem}" + (f" (expected {err.expected})" if err.expected else "")
    if isinstance(err, TimeoutError):
        return f"timed out: {err}" if str(err) else "timed out"
    if isinstance(err, OSError) and err.filename is not None:
        return f"{err.filename}: {err.strerror or err}" + _cache_hint(err.filename)
    return str(err)


def _cache_hint(filename) -> str:
    """Where a file error is inside lightfit's cache (a root that is a file, or not writable), the
    variable that moves it; the path alone did not say the user had a say."""
    try:  # no home folder to find (HOME unset, no passwd entry): no hint, the error itself stands
        root = cache_root()
        inside = Path(os.fsdecode(filename)).absolute().is_relative_to(root.absolute())
    except (TypeError, ValueError, RuntimeError):
        return ""
    return f" (lightfit's cache, {root}: set {ENV_CACHE} to a folder it can write)" if inside else ""


def caution(line: str) -> None:
    """One ``caution: …`` line on stderr: a result to read with care (a fit on its bounds, walkers
    that disagree), said where the numbers are printed but kept out of piped output."""
    err_console.print(f"[yellow]caution[/]: {escape(line)}", soft_wrap=True, highlight=False)


_python_showwarning = warnings.showwarning


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """lightfit's own warnings (e.g. unconverged photosynthesis) as one line ``warning: …`` on
    stderr; others as Python shows them."""
    if category.__module__.startswith("lightfit"):
        err_console.print(f"[bold yellow]warning:[/] {escape(str(message))}", soft_wrap=True, highlight=False)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


def output_folder(out: Path, option: str = "out") -> Path:
    """``out`` as a command's output folder, checked before any work: an existing file there is an
    error naming the option (``mkdir`` said only "File exists", after the run had begun), and so is
    a file where a folder above it would be (``-o results.nc/ds``: "Not a directory" after the run)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} is a file", parameter=option, expected="a folder to write into (created if missing)")
    _no_file_above(out, option, "a folder to write into")
    return out


def _no_file_above(path: Path, option: str, expected: str) -> None:
    """:class:`InputError` naming ``option`` where the nearest existing folder above ``path`` (the
    folders that do not exist are made) is a file."""
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder} is a file, not a folder", parameter=option, expected=expected)


def output_file(path: Path, option: str) -> Path:
    """``path`` as a file a command will write, checked before any work: a folder there is an error
    naming the option (writing said only "Is a directory", after the plants had grown), and so is a
    file where its folder, or a folder above it, would be ("File exists", after the plants had grown)."""
    if path.is_dir():
        raise InputError(f"{path} is a folder", parameter=option, expected="a file name to write")
    _no_file_above(path, option, "a file name in a folder")
    return path


def json_object(path: Path, option: str, expected: str) -> dict:
    """The JSON object in ``path``, a file an option names or a command reads for it: a file that is
    not JSON, cannot be read (a folder) or holds something else is that option's error, naming the
    file, not a traceback."""
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputError(f"not JSON: {err}", file=path, parameter=option, expected=expected) from None
    except OSError as err:
        raise InputError(f"cannot be read ({err.strerror})", file=path, parameter=option, expected=expected) from None
    if not isinstance(data, dict):
        raise InputError(f"holds a JSON {type(data).__name__}", file=path, parameter=option, expected=expected)
    return data


#: ``--theta``'s help, for every command that runs the model at given parameters.
THETA_HELP = (
    "Leaf/light parameters: a calibration.json, a posterior's summary.json (its MAP) or key=value,... "
    "(specular, roughness, subsurface, light_factor, vcmax_scale)."
)


def parse_theta(theta: str | None, option: str = "theta") -> dict[str, float]:
    """Parameters from a JSON file (a calibration's ``calibration.json``: its ``theta``; a posterior's
    ``summary.json``: its MAP, ``x_map``, without the noise scale, which is no model parameter) or
    ``key=value,key=value`` text, each checked against its domain
    (:func:`~lightfit.model.parameters.check_theta`; errors name ``option``)."""
    from lightfit.model.parameters import BOUNDS, check_theta

    if not theta:
        return {}
    p = Path(theta)
    expected = "a calibration.json, a posterior's summary.json or a JSON object of parameter values"
    if p.exists():
        data = json_object(p, option, expected)
        values = data.get("theta", data)
        if "x_map" not in data and {"names", "stopped_by", "rhat"} <= set(data):  # --no-analysis wrote it
            raise InputError(
                "a posterior's summary without its analysis (written by --no-analysis): it has no MAP",
                file=p,
                parameter=option,
                expected=f"a summary with the analysis: rerun `lightfit posterior` into {p.parent} with --analysis "
                "(the default; the chain is resumed, not sampled again)",
            )
        if "x_map" in data:  # a posterior's summary: its MAP (the sampled model parameters)
            values = {k: v for k, v in data["x_map"].items() if k in BOUNDS}
        if not isinstance(values, dict):
            raise InputError(
                f"its theta is a JSON {type(values).__name__}", file=p, parameter=option, expected=expected
            )
        try:
            return check_theta(values, what=option)
        except InputError as err:
            raise err.in_file(p) from None  # the option applied to the file (FILE_OPTIONS)
    if "=" not in theta:  # neither pairs nor an existing file
        raise InputError(
            f"no file {theta!r}",
            parameter=option,
            expected="a JSON file or key=value pairs, e.g. specular=0.4,roughness=0.6",
        )
    out = {}
    for item in theta.split(","):
        k, value = name_value(item, option, "a JSON file or key=value pairs, e.g. specular=0.4,roughness=0.6")
        if k in out:
            raise InputError(f"{k} given more than once", parameter=option, expected="each parameter once")
        out[k] = value
    return check_theta(out, what=option)


def name_value(item: str, option: str, expected: str) -> tuple[str, float]:
    """``"name=number"`` text as (name, number), else :class:`InputError` naming ``option``."""
    k, _, v = item.partition("=")
    try:
        return k.strip(), float(v)
    except ValueError:
        raise InputError(f"cannot read parameter {item!r}", parameter=option, expected=expected) from None


#: Settings that give fitted parameters their meaning: a leaf's specular, roughness and subsurface act
#: on its optics and sky, the light factor on its weather, vcmax_scale on its photosynthesis set.
THETA_CONTEXT = (
    "optics",
    "chlorophyll_ug_cm2",
    "sky",
    "soil_albedo",
    "par_kind",
    "photosynthesis",
    "photosynthesis_overrides",
    "vcmax_profile",
    "growth_temperature_c",
    "weather_file",
)


def theta_cautions(theta: str | None, config: dict) -> list[str]:
    """What to say of parameters taken from a file (:func:`parse_theta`) before they are used in a run of
    settings ``config`` (:meth:`~lightfit.cli.options.ModelSettings.effective`): a calibration that did
    not converge, a posterior whose diagnostics caution (``lightfit posterior``'s own cautions), and a
    fit made with other :data:`THETA_CONTEXT` settings (a calibration's or posterior summary's ``config``;
    for a summary written before it held one, the run.h5 beside it), unset settings of older records taken
    as their defaults (:func:`_effective`)."""
    if not theta or not Path(theta).exists():
        return []
    p = Path(theta)
    data = json_object(p, "theta", "a calibration.json or a posterior's summary.json")
    out, fitted = [], data.get("config")
    if data.get("converged") is False:
        out.append(
            f"{p} is a calibration that did not converge ({data.get('stopped_by')}: {data.get('reason')}): "
            "its theta is where the optimiser stopped, not an optimum"
        )
    if "x_map" in data:
        from lightfit.cli.posterior import _cautions

        try:
            said = _cautions(data)
        except (KeyError, IndexError, TypeError, ValueError):  # a summary edited or written elsewhere
            said = ["its diagnostics (names, rhat, tau, χ², priors) are not those lightfit posterior writes"]
        if said:  # the first in full; `lightfit posterior` printed them all where the numbers were
            more = f" (and {len(said) - 1} more cautions its run printed)" if len(said) > 1 else ""
            out.append(f"the posterior of {p}: {said[0]}{more}")
        if fitted is None and (p.parent / "run.h5").exists():
            from lightfit.inference.mcmc.backend import run_attrs

            try:
                fitted = run_attrs(p.parent / "run.h5").get("config")
            except (InputError, OSError, KeyError):
                fitted = None  # no run file to compare with: nothing said of the settings
    if isinstance(fitted, dict):
        then, now = _effective(fitted), _effective(config)
        differ = [k for k in THETA_CONTEXT if k in fitted and k in config and then[k] != now[k]]
        if differ:
            then = ", ".join(f"{k} {then[k]}" for k in differ)
            now = ", ".join(f"{k} {now[k]}" for k in differ)
            out.append(f"{p} was fitted with {then}; this run has {now}: its parameters may not mean the same here")
    return out


def _effective(config: dict) -> dict:
    """The :data:`THETA_CONTEXT` settings of ``config`` as the run takes them, a weather file by its
    name (the same file given by another path is the same). Runs record them so
    (:meth:`~lightfit.cli.options.ModelSettings.effective`); a record written before holds a default
    as ``None`` (or ``"auto"``), taken here as the library resolves it: the prospect leaf's
    chlorophyll, the set's growth temperature and capacity profile, the bundled weather."""
    from lightfit.light.leaf_optics import leaf_traits
    from lightfit.photosynthesis.canopy import profile_for
    from lightfit.photosynthesis.parameters import growth_temperature
    from lightfit.replication import weather_source

    out = {k: config.get(k) for k in THETA_CONTEXT}
    if out["optics"] not in (None, "prospect"):  # a leaf without traits
        out["chlorophyll_ug_cm2"] = "not used"
    elif out["chlorophyll_ug_cm2"] is None:
        out["chlorophyll_ug_cm2"] = leaf_traits("prospect").Cab
    if out["growth_temperature_c"] is None:
        own = growth_temperature(out["photosynthesis"])  # None: a set that does not acclimate
        out["growth_temperature_c"] = "not used" if own is None else own
    if out["vcmax_profile"] == "auto":
        out["vcmax_profile"] = profile_for("auto", out["photosynthesis"])
    out["weather_file"] = Path(weather_source(out["weather_file"])).name
    return out


def parse_names(text: str) -> tuple[str, ...]:
    """``"a, b,c"`` → ``("a", "b", "c")``."""
    return tuple(n.strip() for n in text.split(",") if n.strip())


_SHORT = {
    "par_umol_m2_s": "PAR",
    "ghi_w_m2": "GHI",
    "dni_w_m2": "DNI",
    "dhi_w_m2": "DHI",
    "sun_elevation_deg": "sun°",
    "tair_c": "T °C",
    "rh": "RH",
    "pair_kpa": "p kPa",
    "co2_ppm": "CO2",
}
_DIGITS = {"rh": 2, "tair_c": 1, "pair_kpa": 1}


#: ``--priors``' help, shared by calibrate and posterior (the ranges: lightfit.inference.mcmc.priors,
#: checked against it in tests/test_cli.py).
PRIORS_HELP = (
    "Prior set: 'informed' (for the default leaf specular 0.4625–0.7375, roughness 0.3–1, subsurface "
    "0.31–1; light factor and vcmax scale log-normal around 1; docs/posterior.md) or 'wide' (specular and "
    "subsurface 0–1)."
)


def fixed(value: float, decimals: int) -> str:
    """``value`` with ``decimals`` decimals, "–" where not finite, and no minus sign on a zero
    (a sun 0.4° below the horizon reads 0, not −0)."""
    v = float(value)
    if not math.isfinite(v):
        return "–"
    text = f"{v:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def weather_table(df, title: str, max_rows: int = 40, tz: str | None = None) -> Table:
    """A weather series as a table: every k-th row, k = ⌊n / ``max_rows``⌋, so fewer than 2 × ``max_rows``
    rows (the bundled day's 144 ten-minute rows as 48, every 30 min), which the caption then says. Local
    times in ``tz`` (default: Selhausen's)."""
    from lightfit.weather.site import SELHAUSEN, local_clock, zone_label

    tz = SELHAUSEN.timezone if tz is None else tz
    step = max(1, len(df) // max_rows)
    shown = "" if step == 1 else f"; 1 row in {step} of {len(df)} shown"
    shown_rows = df.iloc[::step]
    # One UTC date: its clock alone (the date in the caption), so that the table fits 80 columns
    # (a piped run cut the numbers to "16…" beside "04-20 03:00").
    one_day = len(df) > 0 and len(set(df.index.date)) == 1  # the whole series' dates, not only the rows shown
    stamp = "%H:%M" if one_day else "%m-%d %H:%M"
    if one_day:
        shown += f"; UTC date {shown_rows.index[0]:%Y-%m-%d}"
    t = Table(title=title, caption=f"PAR µmol m⁻² s⁻¹; GHI/DNI/DHI W m⁻²; sun° elevation; RH 0–1; CO2 ppm{shown}")
    t.add_column("UTC", no_wrap=True)
    t.add_column(zone_label(tz).split("/")[-1], no_wrap=True)
    cols = [c for c in _SHORT if c in df.columns]
    for c in cols:
        t.add_column(_SHORT[c], justify="right")
    for (ts, row), clock in zip(shown_rows.iterrows(), local_clock(shown_rows.index, tz), strict=True):
        t.add_row(
            ts.strftime(stamp),
            clock,
            *(fixed(row[c], _DIGITS.get(c, 0)) for c in cols),
        )
    return t


def weather_report(df) -> None:
    """Print where a weather series came from, which columns were used and what was repaired."""
    from lightfit.weather import timestamps
    from lightfit.weather.site import zone_label

    a = df.attrs
    console.print(
        f"[bold]source[/] {escape(str(a.get('source')))}  [bold]format[/] {a.get('format')}  "
        f"[bold]provenance[/] [magenta]{a.get('provenance')}[/]  "
        f"[bold]timestamps assumed in[/] {zone_label(str(a.get('timezone_assumed')))}, as the "
        f"{timestamps.of(df).describe()}"
    )
    for k, v in a.get("columns_used", {}).items():
        if k != v:
            console.print(f"  {k:>14} ← {escape(str(v))}")
    if a.get("unused_columns"):
        console.print(f"  [dim]not used: {escape(', '.join(a['unused_columns']))}[/]")
    for q in a.get("qc", []):
        label = (
            "[green]check[/]"
            if q["kind"] in ("checked", "sun at centres")
            else "[cyan]split[/]"
            if q["kind"] == "split"
            else "[yellow]caution[/]"
            if q["kind"] == "caution"
            else f"[yellow]repair[/] {q['kind']}:"
        )
        col = q.get("column")  # the file's own name of the column repaired, where one was
        named = f"{escape(str(a.get('columns_used', {}).get(col, col)))}: " if col else ""
        console.print(f"  {label} {named}{escape(q['detail'])}")


def offset_line(obs, w) -> str:
    """How the observations meet the run's steps: how many are read between two steps (the model
    interpolated linearly in time, :func:`lightfit.inference.observations.interpolation`), and how
    many at their nearest step and how far from it."""
    import numpy as np
    import pandas as pd

    from lightfit.inference.observations import SERIES, interpolation, nearest_steps, with_reading
    from lightfit.weather import timestamps
    from lightfit.weather.reconstruct import Anchor

    stamps = timestamps.of(w)
    idx, dist = nearest_steps(obs, w.index, stamps)
    read = interpolation(obs, w.index, stamps)
    between = np.zeros(len(obs), bool)
    for s in SERIES:
        if s.value in obs.columns:
            between |= obs[s.value].notna().to_numpy() & (read[s.value][1][idx] > 0)
    has = with_reading(obs)  # a row of empty cells is compared with nothing
    at_step, n = has & ~between, int(has.sum())
    parts = []
    if between.any():
        parts.append(
            f"{int(between.sum())} of {n} compared with the model interpolated linearly in time "
            "between the two steps around them"
        )
    if at_step.any():
        far = float(np.max(dist[at_step]) / np.timedelta64(1, "s")) / 60.0
        parts.append(
            f"{int(at_step.sum())} of {n} with their nearest step, up to {far:.1f} min away "
            f"({timestamps.of(obs).describe()} to {stamps.describe()}, by interval centre)"
        )
    anchor = Anchor.of(w.attrs)
    par = obs["above_canopy_par_umol_m2_s"] if "above_canopy_par_umol_m2_s" in obs.columns else None
    if anchor is not None and par is not None:  # a match by construction read as a validation (an audit)
        at = abs(obs.index - anchor.time_utc) <= pd.Timedelta("1min")
        if (at & par.notna().to_numpy()).any():
            parts.append(
                f"the PAR reading at {anchor.time_local} {anchor.tz} is the point the reconstructed forcing "
                "was scaled to: it agrees by construction and validates nothing"
            )
    return "  " + "; ".join(parts)


def observations_for_run(path, w, s):
    """The observations file at ``path`` read for a run of forcing ``w`` and settings ``s``: an SD
    given without its value cautioned (:func:`~lightfit.inference.observations.sd_without_value`),
    canopy An per another area than the run's refused before the plants grow
    (:func:`~lightfit.inference.observations.check_an_area`), then :func:`observations_within_steps`."""
    from lightfit.inference.observations import check_an_area, read_observations, sd_without_value, short_rows

    obs = read_observations(path)
    check_an_area(obs, s.an_per)
    if alone := sd_without_value(obs):
        caution(alone)
    if short := short_rows(obs):
        console.print(f"note: {short}", soft_wrap=True)
    return observations_within_steps(obs, w, s)


def observations_within_steps(obs, w, s):
    """With ``--steps`` (some of each day's steps run), ``obs`` without its rows that lie within the
    days' windows but outside those steps, and a line saying how many were left out: the rest of a
    day's file lies outside on purpose. Rows outside the windows themselves are kept, to be refused
    by :func:`~lightfit.inference.observations.align` (a file of another day or clock), as is
    ``obs`` where no reading falls within the steps. ``w``: the steps' forcing; ``s``: the
    command's :class:`~lightfit.cli.options.ModelSettings`."""
    import numpy as np

    from lightfit.inference.observations import SERIES, far_from_steps, with_reading
    from lightfit.weather import timestamps

    if not s.steps:
        return obs
    cfg = s.replication_config()
    in_windows = np.zeros(len(obs), bool)
    for d in s.dates:
        first, last = cfg.span_utc(d)
        in_windows |= np.asarray((obs.index >= first) & (obs.index <= last))
    out = in_windows & far_from_steps(obs, w.index, timestamps.of(w))  # empty rows too: no part of the steps
    if not out.any() or not (with_reading(obs) & ~out).any():
        return obs
    kept = obs[~out].copy()
    kept.attrs = dict(obs.attrs)
    if len(obs.attrs.get("lines", ())) == len(obs):  # each row's line in the file, for later errors
        kept.attrs["lines"] = tuple(np.asarray(obs.attrs["lines"])[~out].tolist())
    gone = [x.name for x in SERIES if x.value in obs and obs[x.value].notna().any() and kept[x.value].isna().all()]
    console.print(
        f"observations: {int(out.sum())} of {len(obs)} row(s) outside --steps {s.steps} left out "
        f"({obs.attrs.get('source', 'the table')})"
        + (f"; none of the readings of {', '.join(gone)} is within these steps" if gone else ""),
        soft_wrap=True,
    )
    return kept


def check_observations(obs, w) -> None:
    """Observations against the run's forcing, before the plants grow: a light unit slip refused
    (:func:`~lightfit.inference.observations.check_light_scale`), NEE with uptake counted positive
    or PAR that reads as W m⁻² cautioned (:func:`~lightfit.inference.observations.observation_cautions`)."""
    from lightfit.inference.observations import check_light_scale, observation_cautions

    check_light_scale(obs, w)
    for said in observation_cautions(obs, w):
        caution(said)


def observations_lines(obs, w) -> None:
    """Print which observations a command compares with the model and how they meet its steps (what
    replicate, calibrate and posterior read: nothing is dropped or merged unsaid)."""
    from lightfit.inference.observations import with_reading

    # Rows with a reading, as every command counts them (posterior keeps only those before this line).
    n = int(with_reading(obs).sum())
    console.print(f"observations: {obs.attrs['source']} ({obs.attrs['provenance']}, {n} row(s) with a reading)")
    console.print(offset_line(obs, w))


def soil_respiration_note(uses, soil_respiration: float) -> None:
    """A note where chamber NEE is fitted with no soil respiration (``--soil-respiration 0``, the
    default): a chamber's NEE holds it (night readings most), and without it a fit pushes the leaves'
    respiration, tied to vcmax_scale, to stand in for it (a review: two night readings moved
    vcmax_scale from 0.80 to 0.84)."""
    if "nee" in uses and soil_respiration == 0:
        console.print(
            "note: NEE is modelled without soil and root respiration (--soil-respiration 0, the default); a "
            "chamber's NEE contains it, night readings most: give --soil-respiration, or fit daytime NEE"
        )
