"""``lightfit calibrate``: fit leaf surface (and light/Vcmax scale) parameters to observations by gradients."""

from __future__ import annotations

import json
import math
import shlex
from collections.abc import Sequence
from pathlib import Path

import typer
from rich.table import Table

from lightfit.cli.common import (
    CHECK_NOT_PASSED,
    PRIORS_HELP,
    caution,
    check_observations,
    console,
    err_console,
    json_object,
    observations_for_run,
    observations_lines,
    output_folder,
    parse_names,
    parse_theta,
    soil_respiration_note,
)
from lightfit.cli.options import (
    ConnectTimeout,
    DesignWorkers,
    ModelOptions,
    Scheduler,
    Use,
    check_resumable,
    model_options,
    resolve,
    run_model,
    weather,
)
from lightfit.defaults import DESIGN_SIZE
from lightfit.errors import InputError
from lightfit.files import jsonable, replace_text


@model_options
def calibrate(
    ctx: typer.Context,
    observations: Path = typer.Argument(
        ...,
        help="Observations CSV: a time column and a value and SD column for each observed quantity (PAR "
        "above the canopy or at the plants, APAR, fAPAR, canopy net CO2 uptake, NEE, ceptometer series; "
        "the format: data/README.md, Observations).",
    ),
    out: Path = typer.Option(
        Path("results/calibration"),
        help="Output directory: calibration.json (the result), settings.json and the history (trust_region/ "
        "with the surrogate, history.jsonl with --no-surrogate).",
    ),
    parameters: str = typer.Option(
        "specular,roughness,subsurface",
        help="Parameters to calibrate, comma-separated (default: the three leaf parameters).",
        show_default=False,
    ),
    start: str = typer.Option(
        None,
        help="Start values key=value,... of calibrated parameters (default: the run leaf's parameters, light_factor "
        "1, vcmax_scale 1); a value of one not calibrated is refused unless it is the value the run holds.",
    ),
    method: str = typer.Option(
        "lbfgsb",
        help="Optimiser: lbfgsb (jaxopt L-BFGS-B on the natural parameters within their bounds) "
        "or bfgs (optimistix BFGS on logit/log-transformed parameters).",
    ),
    use: Use = "",
    max_steps: int = typer.Option(30, help="Maximum accepted optimiser steps in all (a resumed run's included)."),
    resume: bool = typer.Option(
        True, help="Continue the run in OUT if present (exactly, from its saved optimiser state)."
    ),
    surrogate: bool = typer.Option(
        True,
        "--surrogate/--no-surrogate",
        help="Optimise on the render emulator (the design lightfit posterior uses, cached), checked by full "
        "renders at the optimum (default); --no-surrogate renders at every loss evaluation.",
    ),
    n_design: int = typer.Option(
        None,
        help=f"Emulator design renders (default {DESIGN_SIZE}, the size lightfit posterior uses, so both share one "
        "design).",
    ),
    max_rounds: int = typer.Option(6, help="Surrogate rounds at most (each adds one render at its optimum)."),
    priors: str = typer.Option(
        "informed",
        help=PRIORS_HELP + " Its leaf-parameter support is the emulator's box.",
    ),
    cache: Path = typer.Option(None, help="Design cache (default: $LIGHTFIT_CACHE or ~/.cache/lightfit)."),
    mc_correlation: str = typer.Option(
        "model",
        help="Likelihood's Monte Carlo error: 'model' (its correlation across steps and series, computed once at "
        "the start; the default) or 'independent' (independent steps, the form before issue 15).",
    ),
    mc_scale: float = typer.Option(
        1.0, help="Factor on the model's Monte Carlo variance in the likelihood (2 for twins rendered at another seed)."
    ),
    scheduler: Scheduler = None,
    workers: DesignWorkers = None,
    connect_timeout: ConnectTimeout = 30.0,
    *,
    model: ModelOptions,
) -> None:
    """Calibrate leaf surface (and optionally light_factor, vcmax_scale) parameters by gradients (float64).

    Several --date: one calibration against the observations of every day (each day's plants and forcing).
    --workers / --scheduler: the surrogate's design renders run on a Dask cluster (docs/posterior.md).
    Exit status 3: the surrogate's full-render check did not pass (the result is written, marked
    not converged, but the full renders did not confirm it); 2: bad input.
    A first try (≈ 1 min): lightfit calibrate data/observations/twin_2016-04-20_synthetic.csv --quick
    --n-plants 9 (a SYNTHETIC twin series made by the model on that 9-plant cell; not a measurement)."""
    from lightfit.distributed.design import design_renderer
    from lightfit.distributed.run import check_cluster_options
    from lightfit.inference import mcmc as P
    from lightfit.inference.calibration import METHODS, check_max_steps, check_start_names, fit_cautions, on_edge
    from lightfit.inference.calibration import calibrate as run_calibration
    from lightfit.inference.likelihood import check_informed, likelihood_form, resolve_use
    from lightfit.inference.observations import declared, observation_table_digest
    from lightfit.inference.posterior import prior_set
    from lightfit.inference.trust_region import observed_model, surrogate_calibrate
    from lightfit.model import emulator as E
    from lightfit.model.parameters import BOUNDS, Theta, check_names, interval
    from lightfit.precision import precision

    s = resolve(model)
    output_folder(out)
    check_cluster_options(scheduler, workers=workers, connect_timeout_s=connect_timeout)  # before the plants grow
    if not surrogate and (scheduler is not None or workers is not None):  # they would render nothing
        given = "--scheduler" if scheduler is not None else "--workers"
        raise InputError(
            f"{given} with --no-surrogate",
            parameter="scheduler" if scheduler is not None else "workers",
            expected="--scheduler / --workers only with the surrogate, whose design they render; "
            "--no-surrogate makes its full renders in this process",
        )
    if not surrogate:  # the surrogate's design and rounds: with --no-surrogate they were dropped unsaid
        # By name: typer vendors click, so click's own ParameterSource is another enum.
        given = [n for n in ("n_design", "max_rounds", "cache") if ctx.get_parameter_source(n).name == "COMMANDLINE"]
        if given:
            flags = ", ".join("--" + n.replace("_", "-") for n in given)
            raise InputError(
                f"{flags} with --no-surrogate",
                parameter=given[0],
                expected="--n-design / --max-rounds / --cache only with the surrogate, whose design and rounds "
                "they set; --no-surrogate renders at every loss evaluation",
            )
    # Checked before the model is built (growing the plants can take minutes); calibrate() checks again.
    if method not in METHODS:
        raise InputError(f"method={method!r}", parameter="method", expected=" or ".join(METHODS))
    if priors not in P.PRIOR_SETS:
        raise InputError(f"priors={priors!r}", parameter="priors", expected=" or ".join(P.PRIOR_SETS))
    n_design = DESIGN_SIZE if n_design is None else n_design
    if surrogate:
        E.check_design_size(n_design)  # before any render
    form = likelihood_form(mc_correlation, mc_scale)
    if not (mc_scale >= 0 and mc_scale < float("inf")):
        raise InputError(f"mc_scale={mc_scale!r}", parameter="mc-scale", expected="a finite number ≥ 0")
    if max_rounds < 1:
        raise InputError(f"max_rounds={max_rounds}", parameter="max-rounds", expected="at least 1")
    check_max_steps(max_steps)  # before any render (the surrogate's optimiser runs after the design)
    uses = resolve_use(parse_names(use) or None)  # names checked before the observations are read
    names = check_names(parse_names(parameters), fitted=True)
    th0 = parse_theta(start, "start")
    # a start of a parameter not calibrated would be ignored (held at the run leaf's value): refused
    check_start_names(th0, names, Theta.for_optics(s.replication_config().leaf_optics()))
    given = [n for n in names if n in th0 and n in E.LEAF_PARAMETERS]
    if surrogate and given:
        # The emulator is valid only in its box (the priors' leaf support); calibrate() refuses a
        # start outside it too, but only after the design renders. The leaf is known before the
        # plants grow (the same optics the model gets below).
        support = prior_set(priors, s.replication_config().leaf_optics())
        for n in given:
            lo, hi = support[n].support
            if not lo <= th0[n] <= hi:
                raise InputError(
                    f"--start {n}={th0[n]:g}",
                    parameter="start",
                    expected=f"{n} in [{lo:g}, {hi:g}], the emulator's box (the {priors} priors' support), "
                    "or --no-surrogate (full renders, the whole domain)",
                )
    w = weather(s)
    obs = observations_for_run(observations, w, s)
    check_observations(obs, w)  # a unit slip refused, a sign slip cautioned, before the plants grow
    declared_obs = declared(obs)  # recorded in calibration.json: a fit to a synthetic twin says so
    uses = resolve_use(parse_names(use) or None, obs)  # default: every series the file has
    cfg = s.replication_config()
    config = s.effective(w)  # what the run takes, recorded below (not None for "the default")
    run = {"bounces": cfg.render_bounces(), "par_kind": cfg.par_kind}
    check_informed(names, uses, **run)  # before the plants grow (calibrate() checks again)
    # A history made with other model settings (e.g. the finite field, before periodic became the
    # default) must not be resumed into this run: checked before the plants are grown.
    settings, earlier = out / "settings.json", out / "calibration.json"
    record = "the JSON object an earlier calibrate wrote there, or --no-resume to start afresh"
    stored = {f: json_object(f, "out", record) for f in (settings, earlier) if resume and f.exists()}
    before = stored.get(earlier, {}).get("parameters")
    if before is not None and list(before) != list(names):  # another run's result would be replaced silently
        raise InputError(
            f"{out} holds a calibration of {', '.join(before)}; this run calibrates {', '.join(names)}",
            parameter="out",
            expected="another --out, or --no-resume to replace it",
        )
    # What the answer depends on besides the model: a surrogate rerun re-optimises from the cached
    # renders, so without this it replaced the result of other observations or priors unsaid.
    this_run = {
        "parameters": list(names),
        "surrogate": surrogate,
        "start": dict(th0),
        "method": method,
        "use": list(uses),
        "likelihood": form,
        "observation_table_sha256": observation_table_digest(obs),
    }
    if surrogate:
        this_run |= {"priors": priors, "n_design": n_design}
    if stored and ((out / "history.jsonl").exists() or (out / "trust_region").is_dir()):
        f = next(iter(stored))  # settings.json if there, else calibration.json
        check_resumable(stored[f].get("config"), s, f, "calibration history", w)
        was, read = stored.get(settings, {}).get("calibration"), settings
        if was is None:  # settings written before the record: what the earlier result keeps of it
            r, read = stored.get(earlier, {}), earlier
            sur = r.get("surrogate") or {}
            kept = {k: r.get(k) for k in ("parameters", "method", "use", "likelihood")}
            if r:  # a result of the surrogate has its record, one of full renders none
                kept["surrogate"] = "surrogate" in r
            if surrogate:
                kept |= {"priors": (sur.get("box") or {}).get("priors"), "n_design": sur.get("n_design")}
            was = {k: v for k, v in kept.items() if v is not None}
        if "observation_table_sha256" not in was:
            console.print(
                f"{read} was written before lightfit recorded a calibration's observations and start: "
                f"resuming without comparing them{' (the rest compared)' if was else ''}",
                soft_wrap=True,  # a path stays on one line
            )
        changed = [k for k in this_run if k in was and was[k] != this_run[k]]  # keys a record lacks: not known
        if changed:
            said = [
                "observations (another table: its SHA-256 differs)"
                if k == "observation_table_sha256"
                else f"{k} ({was.get(k)!r} → {this_run[k]!r})"
                for k in changed
            ]
            raise InputError(
                f"the calibration there was run with other {'; '.join(said)}",
                file=read,
                expected="the same settings as that run, --no-resume to start again, or another --out",
            )
    m = run_model(s, w)  # several --date: one model per day
    cut = observed_model(m, obs, uses)  # observations the run's steps cannot match fail before --out is written
    observations_lines(obs, w)  # what is compared, and how it meets the steps: nothing dropped unsaid
    soil_respiration_note(uses, s.soil_respiration)
    out.mkdir(parents=True, exist_ok=True)
    replace_text(settings, json.dumps({"config": config, "calibration": this_run}, indent=2))
    if not resume:  # the run it starts again: its result must not outlive it beside this run's history
        earlier.unlink(missing_ok=True)
    say = lambda x: console.print(x)  # noqa: E731
    tr = None
    box = prior_set(priors, m.scenario.optics)  # the run leaf's priors: the emulator's box, the cautions' ranges
    if surrogate:
        lo = [box[n].support[0] for n in E.LEAF_PARAMETERS]
        hi = [box[n].support[1] for n in E.LEAF_PARAMETERS]
        with design_renderer(scheduler, workers, connect_timeout) as render_points:
            tr = surrogate_calibrate(
                m,
                obs,
                names=names,
                start=th0,
                use=uses,
                lo=lo,
                hi=hi,
                n_design=n_design,
                cache=cache,
                out=out / "trust_region",
                max_rounds=max_rounds,
                method=method,
                max_steps=max_steps,
                say=say,
                mc_correlation=form["mc_correlation"],
                mc_scale=mc_scale,
                render_points=render_points,
            )
        res = tr.result
    else:
        m, obs, _ = cut  # render only the steps the observations need
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
            say=say,
            mc_correlation=form["mc_correlation"],
            mc_scale=mc_scale,
        )
    record = {
        "theta": res.theta,
        "loss": res.loss if math.isfinite(res.loss) else None,  # None: no point had a loss (strict JSON)
        "steps": res.steps,
        "evaluations": res.evaluations,
        "gradients": res.gradients,
        "stopped_by": res.stopped_by,
        "reason": res.reason,
        # Converged means the answer holds: with the surrogate, its optimiser converged *and* the
        # full renders confirmed its loss at the optimum (surrogate.passed).
        "converged": bool(res.converged) and (tr is None or bool(tr.passed)),
        "optimizer_converged": bool(res.converged),
        "method": res.method,
        "use": list(uses),
        "dates": list(getattr(m, "dates", s.dates)),
        "likelihood": form,
        "seconds": res.seconds if tr is None else tr.seconds,
        # the file (absolute: read back from elsewhere it still names it) and what it says it is
        **declared_obs,
        "n_observations": int(res.n_observations),
        "parameters": list(names),
        "config": config,
        "options_given": model.args(),  # what was asked, where config has what it came to ("series" → 9.3 °C)
        "precision": precision(),
    }
    if tr is not None:
        record["surrogate"] = {
            "mode": tr.mode,
            "passed": tr.passed,
            "criterion": f"|full-render loss - surrogate loss| <= {tr.z:g} sigma_L at the optimum "
            "(sigma_L: Monte Carlo SD of the loss, lightfit.inference.trust_region)",
            "loss_full": tr.loss_full,
            "renders_new": tr.rendered,
            "renders_cached": tr.cached,
            "sun_positions_rendered": tr.steps_rendered,
            "n_design": n_design,
            "design_seed": E.DESIGN_SEED,
            "box": {"lo": lo, "hi": hi, "priors": priors},
            "design_dir": None
            if tr.design_dir is None
            else [str(d) for d in tr.design_dir]
            if isinstance(tr.design_dir, list)
            else str(tr.design_dir),
            "rounds": tr.rounds,
        }
    # strict JSON (jq and JavaScript refuse Infinity): a round whose full render's photosynthesis did
    # not converge has loss_full null, not Infinity
    replace_text(out / "calibration.json", json.dumps(jsonable(record, strict=True), indent=2, allow_nan=False))
    t = Table(
        # The counts go below: a title is wrapped to the table's width, and a long one read badly.
        title=f"calibration: {res.method}{' on the emulator' if tr and tr.mode == 'surrogate' else ''}"
        + (", to synthetic observations" if declared_obs["observations_provenance"] == "synthetic" else ""),
        caption=f"{res.steps} accepted steps, {res.evaluations} loss and {res.gradients} gradient evaluations, "
        f"{record['seconds']:.0f} s; stopped: {res.reason}",
    )
    # The range searched: the emulator's box (the priors' leaf support), else the parameters' domains.
    search = {n: BOUNDS[n] for n in names}
    if tr is not None:
        search.update({n: (lo[i], hi[i]) for i, n in enumerate(E.LEAF_PARAMETERS) if n in names})
    t.add_column("parameter")
    t.add_column("value", justify="right")
    t.add_column("searched in", justify="right")
    for k, v in res.theta.items():
        where = "fixed" if k not in search else interval(*search[k])
        t.add_row(k + (" (calibrated)" if k in names else ""), f"{v:.4g}", where)
    surrogate = tr is not None and tr.mode == "surrogate"
    t.add_row("loss ½ rᵀΣ⁻¹r" + (" (emulator)" if surrogate else ""), f"{res.loss:.4g}")
    if surrogate and math.isfinite(tr.loss_full):
        t.add_row("loss ½ rᵀΣ⁻¹r (full renders)", f"{tr.loss_full:.4g}")
    console.print(t)
    if tr is not None:
        _print_check(tr)
    support = {n: p.support for n, p in box.items()}
    if not res.converged:  # said before the fit's cautions, whose "the fit is good" reads as a verdict
        caution(
            f"the optimiser did not converge ({res.reason}): the values are where it stopped, not an optimum; "
            + unconverged_remedy(
                res.stopped_by,
                surrogate=tr is not None,
                method=res.method,
                edges=[n for n in names if on_edge(float(res.theta[n]), *search[n])],
            )
        )
    others = " or ".join(f"--priors {p}" for p in P.PRIOR_SETS if p != priors)
    for line in fit_cautions(res.theta, names, res.loss, res.n_observations, search, support):
        leaf = tr is not None and tr.mode == "surrogate" and line.split(" ", 1)[0] in E.LEAF_PARAMETERS
        if leaf and "on the edge of its search range" in line:  # where that range comes from, and the way out
            line += f" (the emulator's box, the {priors} priors' support; {others} or --no-surrogate searches further)"
        caution(line)
    # The same model (field, days, window, light settings) and these observations, at the fit.
    again = ["lightfit", "replicate", *model.args(), "--theta", str(out / "calibration.json")]
    again += ["--observations", str(observations), "--out", str(out / "fit")]
    console.print(
        f"[green]wrote[/] {out / 'calibration.json'}, {out / 'settings.json'}, "
        f"{out / ('trust_region' if tr else 'history.jsonl')}; "
        f"to see the fit: {shlex.join(again)}",
        soft_wrap=True,
    )
    if tr is not None and not tr.passed:  # said in red above; a script running calibrations must tell too
        err_console.print(
            f"[red]the full-render check did not pass[/]: {out / 'calibration.json'} is not confirmed by the full "
            f"renders (exit status {CHECK_NOT_PASSED})",
            soft_wrap=True,
            highlight=False,
        )
        raise typer.Exit(CHECK_NOT_PASSED)


def unconverged_remedy(
    stopped_by: str, surrogate: bool = False, method: str = "lbfgsb", edges: Sequence[str] = ()
) -> str:
    """What helps a calibration that stopped unconverged (``CalibrationResult.stopped_by``): more steps
    where it ran out of them; elsewhere a rerun restores the same optimiser state and stops the same
    way (a review: "a larger --max-steps" was said after a failed line search too). ``surrogate``: the
    optimisation ran on the emulator (``trust_region.surrogate_calibrate``), whose rounds are not
    resumed but redone from the cached renders, the same steps again. ``edges``: the calibrated
    parameters on the edge of their search range (``calibration.on_edge``) where it stopped; with
    ``method`` bfgs, which works in logit/log coordinates and only approaches a bound, more steps
    do not reach an optimum there: lbfgsb, which steps onto bounds, is advised instead (a review)."""
    if stopped_by in ("max_steps", "stalled") and method == "bfgs" and edges:
        return (
            f"{', '.join(edges)} on the edge of {'its' if len(edges) == 1 else 'their'} search range, which "
            "bfgs (on logit/log-transformed parameters) approaches but never reaches, so a larger --max-steps "
            "does not help: start again (--no-resume or another --out) with --method lbfgsb, which steps onto "
            "bounds"
        )
    if stopped_by in ("max_steps", "stalled"):
        how = "redoes the optimisation on the cached renders" if surrogate else "continues from its history"
        return f"rerun with a larger --max-steps (the run {how})"
    again = "redo the same steps" if surrogate else "resume the same state"
    return (
        f"a larger --max-steps would {again} and stop the same way: start again (--no-resume or "
        "another --out) with the other --method, another --start or fewer --parameters, and check the "
        "observations' units and SDs"
    )


def _print_check(tr) -> None:
    """The full-render check of a surrogate calibration, one row per round."""
    if tr.mode != "surrogate":
        console.print(f"full-render check: not needed ({tr.mode}; the loss was exact); renders: {tr.rendered} new")
        return
    if tr.passed:
        verdict = "[green]passed[/]"
    elif tr.result.stopped_by.startswith("unconverged"):  # the loop ended before this round's check
        verdict = (
            f"[red]not passed: round {len(tr.rounds)}'s optimisation on the emulator stopped before its "
            "full-render check (below: why)[/]"
        )
    else:
        verdict = "[red]not passed within --max-rounds[/]"
    t = Table(
        title=f"full-render check at the optimum (renders for the design and the checks: {tr.rendered} new, "
        f"{tr.cached} from the cache, "
        f"{tr.steps_rendered} sun positions each)",
        caption=f"passes when |full − surrogate| ≤ {tr.z:g} σ_L (σ_L: Monte Carlo SD of the loss); " + verdict,
    )
    for c in ("round", "design", "degree", "surrogate loss", "full-render loss", "σ_L", "|Δ|/σ_L", "check"):
        t.add_column(c, justify="right")
    for r in tr.rounds:
        t.add_row(
            str(r["round"]),
            str(r["design"]),
            str(r["degree"]),
            f"{r['loss_surrogate']:.4g}",
            f"{r['loss_full']:.4g}",
            f"{r['loss_sd']:.3g}",
            f"{r['difference_over_sd']:.2f}",
            "passed" if r["passed"] else "refine",
        )
    console.print(t)
