"""``lightfit calibrate``: fit leaf surface (and light/Vcmax scale) parameters to observations by gradients."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.table import Table

from lightfit.cli.common import console, parse_names, parse_theta
from lightfit.cli.options import ModelOptions, Use, check_resumable, coupled_model, model_options, resolve, weather
from lightfit.errors import InputError


@model_options
def calibrate(
    observations: Path = typer.Argument(..., help="Observations CSV (time, PAR, net CO2 uptake and their SDs)."),
    out: Path = typer.Option(Path("results/calibration"), help="Output directory (history, result JSON, plot)."),
    parameters: str = typer.Option("specular,roughness,subsurface", help="Parameters to calibrate, comma-separated."),
    start: str = typer.Option(None, help="Start values key=value,... (default: 0.5, 0.5, 0.3, 1, 1)."),
    method: str = typer.Option(
        "bfgs",
        help="Optimiser: bfgs (optimistix BFGS on logit/log-transformed parameters) "
        "or lbfgsb (jaxopt L-BFGS-B on the natural parameters within their bounds).",
    ),
    use: Use = "",
    max_steps: int = typer.Option(30, help="Maximum accepted optimiser steps in all (a resumed run's included)."),
    resume: bool = typer.Option(
        True, help="Continue the run in OUT if present (exactly, from its saved optimiser state)."
    ),
    *,
    model: ModelOptions,
) -> None:
    """Calibrate leaf surface (and optionally light_factor, vcmax_scale) parameters by gradients (float64)."""
    from lightfit.inference.calibration import METHODS
    from lightfit.inference.calibration import calibrate as run_calibration
    from lightfit.inference.likelihood import resolve_use
    from lightfit.inference.observations import read_observations
    from lightfit.model.parameters import check_names
    from lightfit.precision import precision

    s = resolve(model)
    # Checked before the model is built (growing the plants can take minutes); calibrate() checks again.
    if method not in METHODS:
        raise InputError(f"method={method!r}", column="method", expected=" or ".join(METHODS))
    uses = resolve_use(parse_names(use) or None)  # names checked before the observations are read
    names = check_names(parse_names(parameters))
    th0 = parse_theta(start)
    check_names(th0, what="start")
    obs = read_observations(observations)
    uses = resolve_use(parse_names(use) or None, obs)  # default: every series the file has
    # A history made with other model settings (e.g. the finite field, before periodic became the
    # default) must not be resumed into this run: checked before the plants are grown.
    settings = out / "settings.json"
    if resume and (out / "history.jsonl").exists():
        for f in (settings, out / "calibration.json"):
            if f.exists():
                check_resumable(json.loads(f.read_text()).get("config"), s, f, "calibration history")
                break
    m = coupled_model(s, weather(s))
    out.mkdir(parents=True, exist_ok=True)
    settings.write_text(json.dumps({"config": s.as_dict()}, indent=2))
    res = run_calibration(
        m,
        obs,
        names=names,
        start=th0,
        method=method,
        use=uses,
        max_steps=max_steps,
        history=out / "history.jsonl",
        resume=resume,
        say=lambda x: console.print(x),
    )
    (out / "calibration.json").write_text(
        json.dumps(
            {
                "theta": res.theta,
                "loss": res.loss,
                "steps": res.steps,
                "evaluations": res.evaluations,
                "gradients": res.gradients,
                "stopped_by": res.stopped_by,
                "reason": res.reason,
                "converged": bool(res.converged),
                "method": res.method,
                "use": list(uses),
                "seconds": res.seconds,
                "observations": str(observations),
                "parameters": list(names),
                "config": s.as_dict(),
                "precision": precision(),
            },
            indent=2,
        )
    )
    t = Table(
        title=f"calibration ({res.method}: {res.steps} accepted steps, {res.evaluations} loss and "
        f"{res.gradients} gradient evaluations, {res.seconds:.0f} s)",
        caption=f"stopped: {res.reason}",
    )
    t.add_column("parameter")
    t.add_column("value", justify="right")
    for k, v in res.theta.items():
        t.add_row(k + (" (calibrated)" if k in names else ""), f"{v:.4g}")
    t.add_row("loss (Gaussian NLL)", f"{res.loss:.4g}")
    console.print(t)
    console.print(
        f"[green]wrote[/] {out / 'calibration.json'}, {out / 'history.jsonl'}; "
        f"rerun `lightfit replicate --theta {out / 'calibration.json'}` to see the fit"
    )
