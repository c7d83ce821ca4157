"""``lightfit calibrate``: fit leaf surface (and light/Vcmax scale) parameters to observations by gradients."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.table import Table

from lightfit.cli.common import console, parse_names, parse_theta
from lightfit.cli.options import ModelOptions, coupled_model, model_options, resolve, weather


@model_options
def calibrate(
    observations: Path = typer.Argument(..., help="Observations CSV (time, PAR, net CO2 uptake and their SDs)."),
    out: Path = typer.Option(Path("results/calibration"), help="Output directory (history, result JSON, plot)."),
    parameters: str = typer.Option("specular,roughness,subsurface", help="Parameters to calibrate, comma-separated."),
    start: str = typer.Option(None, help="Start values key=value,... (default: 0.5, 0.5, 0.3, 1, 1)."),
    max_steps: int = typer.Option(30, help="Maximum optimiser steps."),
    resume: bool = typer.Option(True, help="Continue from the history in OUT if present."),
    *,
    model: ModelOptions,
) -> None:
    """Calibrate leaf surface (and optionally light_factor, vcmax_scale) parameters by gradients (BFGS, float64)."""
    from lightfit.inference.calibration import calibrate as run_calibration
    from lightfit.inference.observations import read_observations
    from lightfit.precision import precision

    s = resolve(model)
    names = parse_names(parameters)
    th0 = parse_theta(start)
    obs = read_observations(observations)
    m = coupled_model(s, weather(s))
    out.mkdir(parents=True, exist_ok=True)
    res = run_calibration(
        m, obs, names=names, start=th0, max_steps=max_steps, history=out / "history.jsonl", resume=resume
    )
    (out / "calibration.json").write_text(
        json.dumps(
            {
                "theta": res.theta,
                "loss": res.loss,
                "steps": res.steps,
                "converged": bool(res.converged),
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
        title=f"calibration ({'converged' if res.converged else 'not converged'}, "
        f"{res.steps} steps, {res.seconds:.0f} s)"
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
