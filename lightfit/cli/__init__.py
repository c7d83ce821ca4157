"""The ``lightfit`` command line: one Typer app, one module per command.

========================  ==============================================================
``lightfit info``          versions, Mitsuba variant, libLLVM, JAX precision (:mod:`.info`)
``lightfit weather …``     read, check, convert and plot weather series (:mod:`.weather`)
``lightfit field``         build, report, export and preview a field (:mod:`.field`)
``lightfit replicate``     the main job, 20 April 2016 (:mod:`.replicate`)
``lightfit calibrate``     gradient calibration against observations (:mod:`.calibrate`)
``lightfit posterior``     emcee posterior and identifiability (:mod:`.posterior`)
``lightfit posterior-status`` progress, τ, ESS, acceptance of a running or finished posterior
``lightfit field-run``     a field's tiles on Dask (:mod:`.field_run`)
``lightfit render-dataset`` labelled images from a results file (:mod:`.render_dataset`)
========================  ==============================================================

The commands that run the coupled model share their field / light / photosynthesis / weather
options (:mod:`.options`). Expected user errors print ``error: …`` on stderr and exit with
status 2 (:class:`.common.LightfitGroup`). Every command makes JAX compute in float64
(:func:`lightfit.precision.use_float64`) before it runs (:class:`.common.LightfitCommand`).

Command modules import their heavy dependencies (JAX, Mitsuba, CPlantBox, pvlib, pandas) inside
the command function, and the defaults their help states from :mod:`lightfit.defaults`, so that
``lightfit --help``, a command's ``--help`` and a usage error stay fast (tests/test_cli.py checks
what they import).
"""

from __future__ import annotations

import atexit
import os
import signal
import sys
import threading

import typer

from lightfit.cli import weather
from lightfit.cli.calibrate import calibrate
from lightfit.cli.common import INTERRUPTED, LightfitCommand, LightfitGroup
from lightfit.cli.field import field
from lightfit.cli.field_run import field_run
from lightfit.cli.info import info
from lightfit.cli.posterior import posterior, posterior_status
from lightfit.cli.render_dataset import render_dataset
from lightfit.cli.replicate import replicate

app = typer.Typer(
    help="Differentiable light and photosynthesis for wheat canopies.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    cls=LightfitGroup,
)


@app.callback()
def _main(
    ctx: typer.Context,
    variant: str = typer.Option(
        None,
        "--variant",
        envvar="LIGHTFIT_VARIANT",
        help="Mitsuba variant, e.g. llvm_ad_mono or cuda_ad_mono (default: auto); given before the command: "
        "lightfit --variant llvm_ad_mono replicate …",
    ),
) -> None:
    """Runs before every command (and before it reads its arguments): the Mitsuba variant if one is
    asked for. The precision policy is the command's own (:class:`.common.LightfitCommand`)."""
    if variant:
        from lightfit.light import backend

        # From LIGHTFIT_VARIANT: the backend reads it itself, so that `lightfit info` says "(env)". By
        # name: typer vendors click, so click's own ParameterSource is another enum.
        from_env = getattr(ctx.get_parameter_source("variant"), "name", "") == "ENVIRONMENT"
        backend.mitsuba(None if from_env else variant)  # a bad variant is a user error (exit 2) before any work


app.command("info", cls=LightfitCommand)(info)
app.add_typer(weather.app, name="weather")
app.command("field", cls=LightfitCommand)(field)
app.command("replicate", cls=LightfitCommand)(replicate)
app.command("calibrate", cls=LightfitCommand)(calibrate)
app.command("posterior", cls=LightfitCommand)(posterior)
app.command("posterior-status", cls=LightfitCommand)(posterior_status)
app.command("field-run", cls=LightfitCommand)(field_run)
app.command("render-dataset", cls=LightfitCommand)(render_dataset)


def main() -> None:
    """The ``lightfit`` console script (and ``python -m lightfit.cli``): :data:`app`, except that an
    interrupted run (exit 130) runs the exit handlers and then leaves without the interpreter's
    teardown, where Dr.Jit's worker threads stopped by Ctrl-C mid-kernel could crash it (exit 139
    after the interrupted line; a review). What a rerun resumes from is on disk already: every
    command survives ``kill -9``. Tests call :data:`app` in their own process, which this leaves alone."""
    try:
        app(prog_name="lightfit")
    except SystemExit as e:
        if e.code != INTERRUPTED:
            code = e.code if isinstance(e.code, int) else int(e.code is not None)
            atexit.register(_teardown_ignores_one_ctrl_c, code)  # registered last: runs first at exit
            raise
        atexit._run_exitfuncs()  # a cluster's close and the quiet exit (common.interrupted) still run
        _leave(INTERRUPTED)


def _teardown_ignores_one_ctrl_c(code: int) -> None:
    """From the first exit handler on (the command has finished and written what it writes), a
    Ctrl-C no longer turns the run into exit 130 without a word (a review): the first is ignored so
    that the exit handlers (a cluster's close) and the interpreter's teardown finish, a second leaves
    at once with the command's status. Only at exit, so a process that called :func:`main` and goes
    on keeps its own Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        return
    pressed = []

    def handler(signum, frame):
        pressed.append(signum)
        if len(pressed) > 1:
            _leave(code)

    signal.signal(signal.SIGINT, handler)


def _leave(code: int) -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
