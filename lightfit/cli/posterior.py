"""``lightfit posterior``: emcee posterior of the leaf optics on emulated renders, then identifiability."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.table import Table

from lightfit.cli.common import (
    PRIORS_HELP,
    caution,
    check_observations,
    console,
    interrupted,
    observations_for_run,
    observations_lines,
    output_folder,
    parse_names,
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
from lightfit.errors import InputError, listed
from lightfit.files import replace_text


@model_options
def posterior(
    ctx: typer.Context,
    observations: Path = typer.Argument(
        None, help="Observations CSV (default: the bundled 2016-04-20 chamber record)."
    ),
    out: Path = typer.Option(Path("results/posterior"), help="Output directory (run.h5, emulator, summary.json)."),
    parameters: str = typer.Option(
        "specular,roughness,subsurface,light_factor",
        help="Sampled parameters, comma-separated (default: the three leaf parameters and light_factor; "
        "also vcmax_scale, noise_scale).",
        show_default=False,
    ),
    priors: str = typer.Option("informed", help=PRIORS_HELP),
    use: Use = "",
    walkers: int = typer.Option(32, help="Walkers (even, ≥ 2 × parameters and ≥ 4)."),
    max_steps: int = typer.Option(
        4000, help="Maximum total steps, a resumed chain's stored steps included (the stop rule usually ends earlier)."
    ),
    target_ess: float = typer.Option(50.0, help="Stop rule: effective samples per parameter."),
    max_minutes: float = typer.Option(
        None, help="Stop sampling after this many minutes (resumable; default: no limit, the stop rule or --max-steps)."
    ),
    sampler_seed: int = typer.Option(0, "--sampler-seed", help="Sampler seed (initial walkers and moves)."),
    n_design: int = typer.Option(
        None,
        help=f"Full renders for the emulator design (default {DESIGN_SIZE}, the size lightfit calibrate uses; kept "
        "in the shared design cache, so a calibration's design serves the posterior).",
    ),
    n_test: int = typer.Option(4, help="Held-out full renders measuring the emulator error (0: no check)."),
    resume: bool = typer.Option(True, help="Continue the run in OUT/run.h5 if present."),
    cache: Path = typer.Option(None, help="Design cache (default: $LIGHTFIT_CACHE or ~/.cache/lightfit)."),
    analysis: bool = typer.Option(
        True, help="After sampling, the analysis (optimum, Fisher, profile, predictive, emulator error)."
    ),
    mc_correlation: str = typer.Option(
        "model",
        help="Likelihood's Monte Carlo error: 'model' (its correlation across steps and series, at the centre of "
        "the priors; the default) or 'independent' (independent steps, the form before issue 15).",
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
    """Sample the posterior with emcee (emulated renders), then Fisher, profile and predictive analysis.

    Several --date: one posterior given the observations of every day (one model and emulator per day).
    --workers / --scheduler: the design and held-out renders run on a Dask cluster (docs/posterior.md)."""

    from lightfit import replication as rep
    from lightfit.distributed.design import design_renderer
    from lightfit.distributed.run import check_cluster_options
    from lightfit.inference import mcmc as P
    from lightfit.inference import posterior as A
    from lightfit.inference.likelihood import likelihood_form, resolve_use, uninformed
    from lightfit.inference.multiday import days_of
    from lightfit.inference.observations import declared
    from lightfit.inference.trust_region import observed_model
    from lightfit.light.bsdf import LEAF_PARAMETERS
    from lightfit.model import emulator as E

    s = resolve(model)
    output_folder(out)
    check_cluster_options(scheduler, workers=workers, connect_timeout_s=connect_timeout)  # before the plants grow
    n_design = E.check_design_size(DESIGN_SIZE if n_design is None else n_design)  # before any render
    stop = P.StopRule(target_ess=target_ess)  # checked before any render
    if max_minutes is not None and not max_minutes > 0:
        raise InputError(f"max_minutes={max_minutes!r}", parameter="max_minutes", expected="> 0 minutes (resumable)")
    if n_test < 0:
        raise InputError(
            f"n_test={n_test}", parameter="n-test", expected="0 (no emulator check) or more held-out renders"
        )
    # By name: typer vendors click, so click's own ParameterSource is another enum.
    if not analysis and n_test and ctx.get_parameter_source("n_test").name == "COMMANDLINE":
        raise InputError(  # the held-out renders are the analysis's emulator check: dropped unsaid without it
            f"--n-test {n_test} with --no-analysis",
            parameter="n_test",
            expected="--n-test only with the analysis (its emulator check), or --n-test 0",
        )
    if priors not in P.PRIOR_SETS:
        raise InputError(f"priors={priors!r}", parameter="priors", expected=" or ".join(P.PRIOR_SETS))
    form = likelihood_form(mc_correlation, mc_scale)
    if not (mc_scale >= 0 and mc_scale < float("inf")):
        raise InputError(f"mc_scale={mc_scale!r}", parameter="mc-scale", expected="a finite number ≥ 0")
    names = P.check_sampled(list(parse_names(parameters)), P.PRIOR_SETS[priors])
    P.check_run_size(len(names), walkers, max_steps, sampler_seed, seed_name="sampler_seed")  # before the design
    w = weather(s)
    obs = observations_for_run(observations or rep.OBSERVATIONS, w, s)
    check_observations(obs, w)  # a unit slip refused, a sign slip cautioned, before the plants grow
    uses = resolve_use(parse_names(use) or None, obs)  # default: every series the file has
    cfg = s.replication_config()
    flat = uninformed(names, uses, bounces=cfg.render_bounces(), par_kind=cfg.par_kind)
    if flat:  # sampled all the same: the posterior then shows it (identical to the prior)
        console.print(
            f"note: no observed series in the likelihood ({', '.join(uses)}) depends on {', '.join(flat)}: "
            "the data cannot inform them, and their posterior is their prior"
        )
    # A stored chain made with other model settings (e.g. the finite field, before periodic became
    # the default) or another likelihood must not be resumed: checked before the plants are grown.
    run_h5 = out / "run.h5"
    _readable_run(run_h5, resume)
    held = P.backend.stored_run(run_h5, "mcmc") if resume else None  # a stored chain's (names, walkers)
    stored = P.backend.run_attrs(run_h5) if held is not None else None  # its attributes only, not the chain
    if stored is not None:
        if held != (tuple(names), walkers):  # the sampler refused these after the plants and design
            raise InputError(
                f"the posterior run there samples {', '.join(held[0])} with {held[1]} walkers; this run asks "
                f"for {', '.join(names)} with {walkers}",
                file=run_h5,
                expected="the run's --parameters and --walkers, --no-resume to start again, or another --out",
            )
        check_resumable(stored.get("config"), s, run_h5, "posterior run", w)
        A.check_likelihood(run_h5, form)
        A.check_resume(run_h5, {"seed": sampler_seed})
        P.check_max_steps(int(stored.get("iteration", 0)), max_steps, run_h5)  # after what says it is another run
    m = run_model(s, w)  # several --date: one model per day
    # Only the steps the observations need are kept, and only those needing the light at the plants rendered.
    m, obs, n_rendered = observed_model(m, obs, uses)
    observations_lines(obs, w)  # what is compared, and how it meets the steps: nothing dropped unsaid
    soil_respiration_note(uses, s.soil_respiration)
    prior_set = A.prior_set(priors, m.scenario.optics)  # informed: the priors of the run's leaf
    lo = [prior_set[n].support[0] for n in LEAF_PARAMETERS]
    hi = [prior_set[n].support[1] for n in LEAF_PARAMETERS]
    # What A.run checks again, here before the design is rendered: the unsampled leaf parameters (the
    # run's own leaf) inside the box, and a stored chain's priors, fixed values, series and observations.
    key = A.resume_key(m, obs, names=names, priors=prior_set, use=uses, seed=sampler_seed)
    A.check_emulator_box(lo, hi, names, prior_set, key["fixed"])
    if resume:
        unchecked = A.check_resume(out / "run.h5", key)
        if unchecked:  # an older run file: resumed as before, without claiming these were compared
            console.print(
                f"{out / 'run.h5'} was written before lightfit recorded its {', '.join(unchecked)}: "
                "resuming it without comparing them"
            )
    out.mkdir(parents=True, exist_ok=True)
    if not resume:  # the run it starts again: its summary must not outlive it (an interrupted run writes none)
        (out / "summary.json").unlink(missing_ok=True)
        (out / "corner.png").unlink(missing_ok=True)
    days = days_of(m)
    dates = getattr(m, "dates", None)  # None: one day (files and keys as before several days existed)
    keys = [E.emulator_key(E.render_key(d), lo, hi, n_design, E.DESIGN_SEED, E.DEGREES) for d in days]
    emu_key = keys[0] if dates is None else dict(zip(dates, keys))
    if stored is not None:  # read above; nothing has written the run file since
        before = stored.get("emulator_key")
        if before is not None and before != emu_key:
            if dates is None or not isinstance(before, dict) or set(before) != set(emu_key):
                changes = "; ".join(E.key_changes(before, emu_key)) if dates is None else "other dates"
            else:
                changes = "; ".join(f"{d}: {c}" for d in dates for c in E.key_changes(before[d], emu_key[d]))
            raise InputError(
                f"the posterior run there was sampled on another emulator ({changes})",
                file=out / "run.h5",
                expected="the run's --n-design, --priors (they set the emulator's leaf box: lo, hi) and model "
                "settings, --no-resume to start again, or another --out",
            )
    if stored is not None:  # said once everything the chain was sampled on has been compared
        console.print(
            f"resuming {out / 'run.h5'}: {stored['iteration']} steps kept, the chain continues from its last step"
        )
    # Design and held-out renders are kept one by one in the shared design cache (an interrupted design
    # continues where it stopped, and lightfit calibrate's design of the same configuration is reused);
    # the emulator is refitted whenever its key (design, box, scene) changed. OUT/emulator.npz is the run's
    # copy (several days: OUT/emulator-<date>.npz, one per day, each day in its own design directory).
    counts, held = dict(E.COUNTS), {"rendered": 0, "cached": 0}  # held: the held-out renders' share
    emus, val = [], []
    with design_renderer(scheduler, workers, connect_timeout) as render_points:
        for i, (d, key) in enumerate(zip(days, keys)):
            copy = out / ("emulator.npz" if dates is None else f"emulator-{dates[i]}.npz")
            stored = E.PartsEmulator.readable(copy, console.print) if copy.exists() else None
            if stored is not None:  # the run's copy: say what changed since this run's last design
                before = stored.key
                if before != key:
                    changes = (
                        "; ".join(E.key_changes(before, key)) if before else "no key (written by an older lightfit)"
                    )
                    console.print(f"emulator {copy} was built for other settings ({changes}): rebuilding")
            emu = E.shared_emulator(
                d,
                lo,
                hi,
                n_design=n_design,
                seed=E.DESIGN_SEED,
                cache=cache,
                progress=True,
                say=lambda x: console.print(x),
                render_points=render_points,
            )
            emu.save(copy)
            emus.append(emu)
            if n_test > 0 and analysis and n_rendered > 0:
                leaf_test = E.sobol_design(n_test, lo, hi, seed=E.HELD_OUT_SEED)
                renders = E.design_dir(d, cache) / "renders"
                start = dict(E.COUNTS)
                if render_points is not None:
                    render_points(d, leaf_test, renders, E.render_key(d), label=E.HELD_OUT_LABEL)
                check = E.render_parts(d, leaf_test, progress=True, cache=renders, label=E.HELD_OUT_LABEL)
                val.append((leaf_test, check))
                held = {k: held[k] + E.COUNTS[k] - start[k] for k in held}
    where = ", ".join(str(E.design_dir(d, cache)) for d in days)
    new, cached = (E.COUNTS[k] - counts[k] - held[k] for k in ("rendered", "cached"))
    checked = f"; held-out check: {held['rendered']} new, {held['cached']} from the cache" if val else ""
    each = f"{n_rendered} sun positions each; {where}"
    reused = E.COUNTS["reused"] - counts["reused"]
    if reused:  # nothing rendered or read because the fitted emulator was stored: not "no design"
        checked += f"; the stored emulator{'s' if reused > 1 else ''} of {n_design} design points reused" + (
            f" for {reused} of {len(days)} days" if 1 < len(days) != reused else ""
        )
    renders = f"{new} new renders, {cached} from the cache" if new or cached or not reused else "no renders"
    if n_rendered == 0:  # "no renders (0 sun positions each; …)" read as a design that failed (an audit)
        console.print("design: none needed (the observed series depend on no rendered light)")
    else:
        console.print(f"design: {renders} ({each}){checked}")
    # config: what the run takes; options_given: what was asked ("series", bounces left to the rule).
    # In the summary too: it is what `--theta OUT/summary.json` and readers take, without run.h5.
    settings = {"config": s.effective(w), "options_given": model.args()}
    res = A.run(
        m,
        obs,
        emus[0] if dates is None else emus,
        out / "run.h5",
        names=names,
        priors=prior_set,
        use=uses,
        nwalkers=walkers,
        max_steps=max_steps,
        seed=sampler_seed,
        resume=resume,
        stop=stop,
        validation_renders=(val[0] if dates is None else val) if val else None,
        # the MAP's leaf rendered into the design's cache, as the held-out points are
        render_at=lambda d, leaf: E.render_parts(d, leaf, progress=False, cache=E.design_dir(d, cache) / "renders"),
        analysis=analysis,
        max_seconds=None if max_minutes is None else 60 * max_minutes,
        attrs={**settings, "priors_set": priors, "emulator_key": emu_key},
        mc_correlation=form["mc_correlation"],
        mc_scale=mc_scale,
        say=lambda line: console.print(line),
    )
    if val:
        res["seeds"]["held_out_design"] = E.HELD_OUT_SEED
    if res["stopped_by"] == "interrupted":  # Ctrl-C while sampling: every finished step is kept
        _print_status(P.backend.run_status(out / "run.h5"))
        interrupted(f"{out / 'run.h5'} keeps every finished step", started_over=not resume)
    # strict JSON: an unbounded Fisher width (eigenvalue 0) is null, not Infinity. Not written when
    # interrupted: it replaced the last finished run's summary with a part of a chain.
    # the observations' file and what it says it is (a fit to a synthetic twin says so without run.h5)
    summary = P.jsonable(res | settings | declared(obs), strict=True)
    if not analysis:
        st = P.backend.run_status(out / "run.h5")
        # A chain not extended by this call keeps its stored analysis (A.run drops it otherwise): its
        # summary and corner plot describe it still (they were replaced by the sampling's alone and removed).
        kept = st["analysis"] and (out / "summary.json").exists()
        if not kept:
            replace_text(out / "summary.json", json.dumps(summary, indent=2, default=str, allow_nan=False))
            (out / "corner.png").unlink(missing_ok=True)  # drawn from a shorter chain, if from this run at all
        _print_status(st)
        if kept:
            files = [str(out / f) for f in ("summary.json", "corner.png") if (out / f).exists()]
            console.print(
                f"[green]kept[/] {out / 'run.h5'}: the chain was not extended, so its stored analysis and "
                f"{' and '.join(files)} still describe it"
            )
        else:
            console.print(f"[green]wrote[/] {out / 'run.h5'}; rerun with --analysis (the default) to analyse it")
        return
    replace_text(out / "summary.json", json.dumps(summary, indent=2, default=str, allow_nan=False))
    refused = res["refused"]
    why = "photosynthesis unconverged or likelihood not finite"
    t = Table(
        title=f"posterior{' to synthetic observations' if obs.attrs.get('provenance') == 'synthetic' else ''} "
        f"({res['stopped_by']}, {res['n_steps']} steps; this call sampled {res['steps_this_call']} "
        f"in {res['seconds_sampling']:.0f} s" + (f", {refused} proposals refused: {why}" if refused else "") + ")"
    )
    for c in ("parameter", "mean", "sd", "MAP", "τ (steps)", "ESS", "R̂"):
        t.add_column(c, justify="right")
    for i, n in enumerate(res["names"]):
        t.add_row(
            n,
            f"{res['mean'][n]:.4g}",
            f"{res['sd'][n]:.3g}",
            f"{res['x_map'][n]:.4g}",
            _shown(res["tau"][i], ".1f"),
            _shown(res["ess"][i], ".0f"),
            _shown(res["rhat"][i], ".3f"),
        )
    console.print(t)
    for line in _cautions(res):  # what posterior-status reports, said where the numbers are
        caution(line)
    console.print(_directions(res))
    from lightfit.inference.plots import corner_figure

    samples = P.flat_samples(P.backend.load_run(out / "run.h5"), stop.burn_fraction)
    said = f"{res['stopped_by']} after {res['n_steps']} steps × {walkers} walkers"
    source = Path(observations or rep.OBSERVATIONS).name
    corner_figure(samples, res["names"], res["x_map"], out / "corner.png", title=f"posterior, {source}: {said}")
    if "emulator_error" in res:
        ee = res["emulator_error"]
        at_map = ee.get("at_map_shift_over_sd")
        held = int(ee["n_test"]) - (at_map is not None)
        console.print(
            f"emulator error → max shift {ee['max_shift_over_sd']:.3g} posterior SD over {held} held-out "
            + ("render" if held == 1 else "renders")
            + ("" if at_map is None else f" and the MAP's leaf ({at_map:.3g} there)")
        )
    console.print(
        f"[green]wrote[/] {out / 'run.h5'}, {out / 'summary.json'}, {out / 'corner.png'}; for chains, profiles and "
        "the predictive curves open notebooks/posterior_analysis.ipynb "
        f"with LIGHTFIT_POSTERIOR_RUN={(out / 'run.h5').resolve()}"  # Jupyter runs it in notebooks/
    )


def _directions(res: dict) -> str:
    """The stiffest and sloppiest combinations of ``res["fisher"]`` (its table, stiff to sloppy) with
    their 1σ widths and units, and how many directions the data leave free (eigenvalue 0): the
    combinations alone read the same whether the data fix a direction to 1 % or say nothing of it."""
    import math

    table = res.get("fisher") or []
    if not table:
        return f"stiffest: {res['stiff']}   sloppiest: {res['sloppy']}"
    scale = table[0].get("width_scale", "log")
    units = "in log units (relative)" if scale == "log" else "in the parameters' own units"

    def bounded(row) -> bool:  # null in summary.json, inf in the run's own table
        w = row.get("width_1sigma")
        return w is not None and math.isfinite(w)

    def width(row) -> str:
        return f"{row['width_1sigma']:.3g}" if bounded(row) else "∞"

    free = sum(not bounded(row) for row in table)
    line = (
        f"stiffest: {res['stiff']} (1σ width {width(table[0])})   sloppiest: {res['sloppy']} "
        f"(1σ width {width(table[-1])}); Fisher widths {units}"
    )
    if free:
        line += (
            f"; {free} of {len(table)} directions not identifiable (Fisher eigenvalue 0: the data say nothing "
            f"along {'it' if free == 1 else 'them'}, only the priors do)"
        )
    return line


def _acceptance_over(d: dict) -> str:
    """The steps the diagnostics' acceptance is over, for a message (``acceptance_steps``)."""
    return {"kept": " (kept steps)", "all": " (all steps)"}.get(d.get("acceptance_steps"), "")


def _cautions(d: dict) -> list[str]:
    """What a posterior's diagnostics ``d`` (a run's summary or its stored diagnostics) warn of:
    walkers that never moved over the kept steps, walkers that disagree (split-R̂, separate modes),
    τ not yet reliable by the stop rule's own multiple, an acceptance outside 0.1–0.8, a MAP the
    optimiser did not reach, a MAP whose χ² the data reject or that sits on its prior's edge, a
    parameter the data hardly narrowed (posterior SD ≥ ``UNINFORMED_SD_RATIO`` of its prior's), an
    emulator whose measured error moves the posterior by more than ``EMULATOR_SHIFT_CAUTION_SD``.
    ``d["corner_png"]`` False: the run has no corner plot of this chain to point to (default: it has)."""
    import numpy as np

    from lightfit.inference.calibration import misfit, on_edge
    from lightfit.inference.mcmc.diagnostics import ACCEPTANCE_OK, StopRule
    from lightfit.inference.posterior import EMULATOR_SHIFT_CAUTION_SD, UNINFORMED_SD_RATIO

    out = []
    names, rhat = list(d.get("names", [])), np.asarray(d.get("rhat", []), float)
    limit = d.get("rhat_max", StopRule().rhat_max)
    stuck = list(d.get("stuck") or [])
    if stuck:  # emcee's τ is NaN while a walker stands still: the τ and R̂ lines below would blame the length
        out.append(
            f"{len(stuck)} of {d.get('n_walkers', '?')} walkers never moved over the kept steps (walker "
            f"{listed(stuck, 8)}): each repeats one point in the samples, which the summary and corner.png average in, "
            "and τ and ESS cannot be estimated; a longer chain does not help: look at where they sit (a spike "
            "or a refused region of the log-probability) and start again (--no-resume, another --sampler-seed)"
        )
    if rhat.size and np.isnan(rhat).any():
        if not stuck:  # else NaN as 0/0: no walker moved
            out.append("split-R̂ cannot be computed yet (fewer than 4 kept steps): nothing says the walkers agree")
    elif rhat.size and rhat.max() >= limit:
        i = int(np.argmax(rhat))
        # corner.png is drawn with the analysis: a run without one has none, or an earlier chain's
        corner = " (the run's corner.png shows where they are)" if d.get("corner_png", True) else ""
        out.append(
            f"the walkers disagree (split-R̂ {rhat[i]:.3g} for {names[i]}, ≥ {limit:g}): the chain has not mixed "
            f"yet ({_going_on(d)}), or they sit in separate modes, whose shares the ensemble "
            f"cannot correct; either way the summary is not the posterior{corner}"
        )
    if not d.get("tau_reliable", True) and not stuck:
        m = d.get("tau_multiple") or 50
        out.append(
            f"τ is not reliable yet (fewer than {m:g} τ kept steps, the stop rule's length): the SDs, τ and ESS "
            f"are rough; {_going_on(d)}"
        )
    if not d.get("acceptance_ok", True):
        lo, hi = ACCEPTANCE_OK
        out.append(
            f"acceptance{_acceptance_over(d)} {d.get('acceptance_mean', float('nan')):.2f} outside {lo:g}–{hi:g}: "
            "the walkers move badly"
        )
    if "chi2_map" in d:  # the posterior of a model the data reject describes that model, not the leaf
        lam = (d.get("x_map") or {}).get("noise_scale")
        if lam is None:
            why = ": the posterior SDs are those of a model the data reject"
        else:  # the sampled noise scale took the misfit up: the SDs are widened by it, not wrong
            why = (
                f" against the stated SDs: the data scatter {lam:.3g} × them at the MAP (noise_scale), which "
                "widens the posterior"
            )
        k = len([n for n in names if n != "noise_scale"])  # λ does not enter χ² taken at λ = 1
        out += [line + why for line in misfit(d["chi2_map"], d["n_observations"], k, what="the MAP")]
    uninformed = {n: r for n, r in (d.get("sd_over_prior_sd") or {}).items() if r >= UNINFORMED_SD_RATIO}
    edges = {}
    for n, (lo, hi) in (d.get("prior_support") or {}).items():
        v = (d.get("x_map") or {}).get(n)
        if v is not None and on_edge(v, lo, hi):
            edges[n] = f"MAP = {v:.4g}", f"on the edge of its prior's range [{lo:g}, {hi:g}]"
            if n not in uninformed:  # an uninformed one's edge is where a nearly flat likelihood tips it: below
                out.append(f"{n}'s {edges[n][0]} is {edges[n][1]}: the data pull it on")
    for n, r in uninformed.items():
        edge = f"; its {' '.join(edges[n])} is where a nearly flat likelihood tips it" if n in edges else ""
        out.append(f"the data hardly inform {n}: its posterior SD is {r:.2f} × its prior's (the prior speaks{edge})")
    if d.get("map_converged") is False:
        where = "the best sample it started from" if d.get("map_kept_start") else "the best point it reached"
        out.append(f"the MAP search did not converge ({d.get('map_message')}): MAP is {where}")
    ee = d.get("emulator_error") or {}
    shift, norm = ee.get("max_shift_over_sd"), ee.get("max_whitened_error_norm")
    # With the sampled covariance the posterior's, (JᵀJ + prior precision)⁻¹, the shift is at most the
    # whitened error's norm (Cauchy–Schwarz); a chain not yet mixed samples wider and inflates the shift,
    # which the R-hat and tau cautions then name: the emulator is called out only where its error is that large.
    if shift is not None and float(shift) > EMULATOR_SHIFT_CAUTION_SD and float(norm or 0) > EMULATOR_SHIFT_CAUTION_SD:
        at_map = ee.get("at_map_shift_over_sd")
        where = "" if at_map is None else f"; {float(at_map):.2g} at the MAP's leaf"
        out.append(
            f"the emulator's measured error moves the posterior mean by up to {float(shift):.2g} posterior SD "
            f"(above {EMULATOR_SHIFT_CAUTION_SD:g}{where}): the intervals are off by that much; a larger design "
            "(--n-design 40 allows a cubic emulator where 20 caps it at quadratic) lowers it, most near the box's "
            "corners"
        )
    return out


def _going_on(d: dict) -> str:
    """How a chain too short for its diagnostics gets longer, by why it stopped (``d``'s ``state`` of
    :func:`~lightfit.inference.mcmc.backend.run_status` or ``stopped_by``): a run cut short by Ctrl-C, a
    kill or ``--max-minutes`` resumes by the same command; one that used its ``--max-steps`` needs more."""
    if d.get("state") == "running":
        return "it is still running"
    if d.get("state") == "killed" or d.get("stopped_by") in ("interrupted", "max_seconds"):
        return "rerun the same command to resume it"
    return "resume with a larger --max-steps"


def posterior_status(
    run: Path = typer.Argument(..., help="A posterior run: its OUT directory or the run.h5 in it."),
) -> None:
    """Progress, τ, ESS and acceptance of a posterior run, while it is written or after it ended."""
    from lightfit.inference.mcmc.backend import run_status

    path = run / "run.h5" if run.is_dir() else run
    if not path.exists():
        raise InputError("no such run", file=path, expected="a directory written by `lightfit posterior` or its run.h5")
    try:
        status = run_status(path)
    except (OSError, KeyError) as e:
        raise InputError(f"not readable as a posterior run ({e})", file=path, expected="an HDF5 run file") from None
    _print_status(status)


def _readable_run(path: Path, resume: bool) -> None:
    """A run file HDF5 cannot open (a kill inside its write; the writes are not atomic): refused naming
    it, or with ``--no-resume``, which starts the run again, removed (it ended in h5py's traceback)."""
    from lightfit.inference.mcmc.backend import open_h5

    if not path.exists():
        return
    if path.is_dir():
        raise InputError("a folder, not a run file", file=path, expected="a run.h5 file, or another --out")
    try:
        with open_h5(path):
            pass
    except OSError as e:
        if resume:
            raise InputError(
                f"not readable as a posterior run ({e})",
                file=path,
                expected="a run file written by lightfit posterior, or --no-resume to start the run again",
            ) from None
        path.unlink()
        console.print(f"{path} was not readable as a posterior run ({e}): removed, the run starts again")


def _shown(x, spec: str) -> str:
    """``x`` formatted by ``spec``, or "–" where it is not a finite number yet (τ, ESS and R̂ of a chain
    too short to estimate them printed as "nan")."""
    import math

    return format(x, spec) if x is not None and math.isfinite(x) else "–"


def _print_status(st: dict) -> None:
    """The table of :func:`lightfit.inference.mcmc.backend.run_status`."""
    import numpy as np

    from lightfit.inference.mcmc.diagnostics import ACCEPTANCE_OK

    d = st["diagnostics"]
    state = {"running": "running", "killed": "ended without finishing (resumable)"}.get(
        st["state"], f"stopped: {st['stopped_by']}"
    )
    t = Table(title=st["path"])
    for c in ("parameter", "τ (steps)", "ESS", "τ at last check", "ESS at last check"):
        t.add_column(c, justify="right")
    last = st["last_check"]
    for i, n in enumerate(st["names"]):
        t.add_row(
            n,
            _shown(d["tau"][i], ".1f"),
            _shown(d["ess"][i], ".0f"),
            "–" if last is None else _shown(last["tau"][i], ".1f"),
            "–" if last is None else _shown(last["ess"][i], ".0f"),
        )
    console.print(t)
    # a run stored before its max_steps was recorded read "150/None steps"
    of = f"/{st['max_steps']} steps" if st.get("max_steps") is not None else " steps (its --max-steps not recorded)"
    console.print(f"{st['steps']}{of}, {state}")
    acc = d.get("acceptance_mean", float("nan"))
    flag = "" if d.get("acceptance_ok", True) else " (outside {:g}–{:g})".format(*ACCEPTANCE_OK)
    check = "no stop-rule check yet" if last is None else f"last stop-rule check at step {last['step']}"
    rhat = np.asarray(d["rhat"], float)
    console.print(
        f"acceptance{_acceptance_over(d)} {_shown(acc, '.2f')}{flag}; "
        f"τ reliable (n_kept ≥ {d['tau_multiple']:g} τ, the stop rule's length; "
        f"emcee suggests 50): {'yes' if d['tau_reliable'] else 'no'}; "
        f"max split-R̂ {_shown(np.nanmax(rhat) if np.isfinite(rhat).any() else None, '.3f')}; {check}; "
        f"max τ {_shown(np.nanmax(d['tau']) if np.isfinite(d['tau']).any() else None, '.1f')}; "
        f"analysis {'written' if st['analysis'] else 'not written'}"
    )
    ms = st.get("map_search") or {}
    map_info = {
        "map_converged": ms.get("converged"),
        "map_message": ms.get("message"),
        "map_kept_start": ms.get("kept_start"),
    }
    said = {"names": st["names"], **d, "acceptance_ok": True, **map_info, "emulator_error": st.get("emulator_error")}
    said |= {"state": st["state"], "stopped_by": st["stopped_by"]}  # how the chain goes on
    said["corner_png"] = bool(st["analysis"]) and Path(st["path"]).with_name("corner.png").exists()
    said |= st.get("fit") or {}  # the MAP's χ², its place in the prior, the priors' say
    for line in _cautions(said):  # acceptance said above
        caution(line)
    if st["refused"]:
        console.print(
            f"{st['refused']} proposals refused (log-probability −inf): the leaf photosynthesis did not "
            "converge or the likelihood was not finite there"
        )
