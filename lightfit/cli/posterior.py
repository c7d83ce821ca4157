"""``lightfit posterior``: emcee posterior of the leaf optics on emulated renders, then identifiability."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.table import Table

from lightfit.cli.common import console, parse_names
from lightfit.cli.options import (
    RENDER_SETTINGS,
    ModelOptions,
    Use,
    changed_settings,
    check_resumable,
    coupled_model,
    model_options,
    resolve,
    weather,
)
from lightfit.errors import InputError


@model_options
def posterior(
    observations: Path = typer.Argument(
        None, help="Observations CSV (default: the bundled 2016-04-20 chamber record)."
    ),
    out: Path = typer.Option(Path("results/posterior"), help="Output directory (run.h5, emulator, summary.json)."),
    parameters: str = typer.Option(
        "specular,roughness,subsurface,light_factor",
        help="Sampled parameters, comma-separated (also vcmax_scale, noise_scale).",
    ),
    priors: str = typer.Option("informed", help="Prior set: 'informed' (docs/design.md §6 leaf optics) or 'wide'."),
    use: Use = "",
    walkers: int = typer.Option(32, help="Walkers (even, ≥ 2 × parameters)."),
    max_steps: int = typer.Option(4000, help="Maximum total steps (the stop rule usually ends earlier)."),
    target_ess: float = typer.Option(50.0, help="Stop rule: effective samples per parameter."),
    max_minutes: float = typer.Option(None, help="Stop sampling after this many minutes (resumable)."),
    sampler_seed: int = typer.Option(0, "--sampler-seed", help="Sampler seed (initial walkers and moves)."),
    n_design: int = typer.Option(40, help="Full renders for the emulator design (cached in OUT)."),
    n_test: int = typer.Option(4, help="Held-out full renders measuring the emulator error."),
    resume: bool = typer.Option(True, help="Continue the run in OUT/run.h5 if present."),
    *,
    model: ModelOptions,
) -> None:
    """Sample the posterior with emcee (emulated renders), then Fisher, profile and predictive analysis."""
    import numpy as np

    from lightfit import replication as rep
    from lightfit.inference import mcmc as P
    from lightfit.inference import posterior as A
    from lightfit.inference.likelihood import resolve_use
    from lightfit.inference.observations import read_observations
    from lightfit.light.bsdf import LEAF_PARAMETERS
    from lightfit.model import emulator as E

    s = resolve(model)
    if priors not in P.PRIOR_SETS:
        raise InputError(f"priors={priors!r}", column="priors", expected=" or ".join(P.PRIOR_SETS))
    prior_set = P.PRIOR_SETS[priors]
    names = P.check_sampled(list(parse_names(parameters)), prior_set)
    obs = read_observations(observations or rep.OBSERVATIONS)
    uses = resolve_use(parse_names(use) or None, obs)  # default: every series the file has
    # A stored chain made with other model settings (e.g. the finite field, before periodic became
    # the default) must not be resumed: checked before the plants are grown.
    if resume and P.backend.stored_run(out / "run.h5", "mcmc") is not None:
        check_resumable(P.load_run(out / "run.h5")["attrs"].get("config"), s, out / "run.h5", "posterior run")
    m = coupled_model(s, weather(s))
    lo = [prior_set[n].support[0] for n in LEAF_PARAMETERS]
    hi = [prior_set[n].support[1] for n in LEAF_PARAMETERS]
    out.mkdir(parents=True, exist_ok=True)
    emu_path, emu_settings = out / "emulator.npz", out / "emulator_settings.json"
    emu = E.PartsEmulator.load(emu_path) if emu_path.exists() else None
    # A cached emulator is reused only if it was built for the same prior box, the same model size
    # and the same render settings (boundary included; an emulator without its settings file
    # predates them and is rebuilt).
    stale = not emu_settings.exists() or changed_settings(json.loads(emu_settings.read_text()), s, RENDER_SETTINGS)
    if (
        emu is None
        or stale
        or not (np.allclose(emu.lo, lo) and np.allclose(emu.hi, hi))
        or emu.coef_values.shape[1:] != (int(m.day.sum()), 4, len(m.segment_id))
    ):
        emu = E.build_emulator(m, lo, hi, n_design=n_design, seed=0, progress=True)
        emu.save(emu_path)
        emu_settings.write_text(json.dumps(s.as_dict(), indent=2))
        (out / "validation.npz").unlink(missing_ok=True)  # renders of the old model
    val_path = out / "validation.npz"
    if val_path.exists() and np.load(val_path)["values"].shape[1:] == emu.coef_values.shape[1:]:
        z = np.load(val_path)
        val = (z["leaf_test"], (z["values"], z["se"]))
    else:
        leaf_test = E.sobol_design(max(n_test, 1), lo, hi, seed=1)[:n_test]
        full = E.render_parts(m, leaf_test, progress=True)
        np.savez_compressed(val_path, leaf_test=leaf_test, values=full[0], se=full[1])
        val = (leaf_test, full)
    res = A.run(
        m,
        obs,
        emu,
        out / "run.h5",
        names=names,
        priors=prior_set,
        use=uses,
        nwalkers=walkers,
        max_steps=max_steps,
        seed=sampler_seed,
        resume=resume,
        stop=P.StopRule(target_ess=target_ess),
        validation_renders=val if n_test > 0 else None,
        max_seconds=None if max_minutes is None else 60 * max_minutes,
        attrs={"config": s.as_dict(), "priors_set": priors},
    )
    (out / "summary.json").write_text(json.dumps(P.jsonable(res), indent=2, default=str))
    t = Table(
        title=f"posterior ({res['stopped_by']}, {res['n_steps']} steps, {res['seconds_sampling']:.0f} s sampling)"
    )
    for c in ("parameter", "mean", "sd", "MAP", "τ (steps)", "ESS"):
        t.add_column(c, justify="right")
    for i, n in enumerate(res["names"]):
        t.add_row(
            n,
            f"{res['mean'][n]:.4g}",
            f"{res['sd'][n]:.3g}",
            f"{res['x_map'][n]:.4g}",
            f"{res['tau'][i]:.1f}",
            f"{res['ess'][i]:.0f}",
        )
    console.print(t)
    console.print(f"stiffest: {res['stiff']}   sloppiest: {res['sloppy']}")
    if "emulator_error" in res:
        console.print(f"emulator error → max shift {res['emulator_error']['max_shift_over_sd']:.3g} posterior SD")
    console.print(
        f"[green]wrote[/] {out / 'run.h5'}, {out / 'summary.json'}; open notebooks/posterior_analysis.ipynb "
        f"with LIGHTFIT_POSTERIOR_RUN={out / 'run.h5'}"
    )
