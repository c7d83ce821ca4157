"""Profile likelihood where only part of the line is allowed (lightfit.inference.identifiability)."""

from __future__ import annotations

import numpy as np
import pytest

from lightfit.inference.identifiability import offsets_in_box, profile_likelihood


def test_the_profile_is_infinite_where_no_allowed_point_exists():
    """nll = (x₀ − 3)² + x₁², profiled along x₀ through (1, 0) with x₀ allowed in [0.5, 1.5]: inside,
    the other direction goes to x₁ = 0 and the profile is (x₀ − 3)²; outside, no point of the offset
    is allowed, and the profile is +∞ (it took the slice there, an extrapolation of the posterior's
    emulator beyond its box: 1.0 at x₀ = 2, below every allowed value)."""
    ts = np.array([-0.5, 0.0, 0.5, 1.0, -1.0])
    _, prof, slc = profile_likelihood(
        lambda x: (x[0] - 3.0) ** 2 + x[1] ** 2,
        np.array([1.0, 0.0]),
        np.array([1.0, 0.0]),
        ts,
        scale="natural",
        box=([0.5, -np.inf], [1.5, np.inf]),
    )
    x0 = 1.0 + ts
    np.testing.assert_allclose(slc, (x0 - 3.0) ** 2, rtol=1e-12)  # the slice goes wherever the line goes
    inside = (x0 >= 0.5) & (x0 <= 1.5)
    np.testing.assert_allclose(prof[inside], (x0[inside] - 3.0) ** 2, atol=1e-9)
    assert np.all(prof[~inside] == np.inf), prof


def test_the_profile_through_a_corner_of_the_box_starts_each_offset_inside_it():
    """A posterior's MAP on its prior box's corner (the review's: specular and subsurface at their
    lower bounds, roughness at its upper one) put the warm start of every other offset outside the box,
    where the objective is flat +∞: the profile was +∞ at all offsets but 0, and the notebook's
    profile panel showed one point, though the box holds points at small offsets. Here the box is
    [0, 1]², the line through its corner (0, 0) along (1, −1)/√2 leaves it at once, the box meets
    the offset's line for |t| ≤ √2/2; reference: the constrained minimum on a fine grid (the line
    search stops short of the boundary: within 2 %)."""
    ts = np.array([-1.0, -0.5, -0.2, 0.0, 0.2, 0.5, 1.0])
    _, prof, _ = profile_likelihood(
        lambda x: (x[0] - 0.2) ** 2 + (x[1] - 0.2) ** 2,
        np.zeros(2),
        np.array([1.0, -1.0]),
        ts,
        scale="natural",
        box=(np.zeros(2), np.ones(2)),
    )
    g = np.linspace(0.0, 1.0, 2001)
    x0, x1 = np.meshgrid(g, g)
    ref = []
    for t in ts:
        on = np.abs((x0 - x1) / np.sqrt(2) - t) < 1e-3
        ref.append(np.min(((x0 - 0.2) ** 2 + (x1 - 0.2) ** 2)[on]) if on.any() else np.inf)
    ref = np.asarray(ref)
    assert np.array_equal(np.isinf(prof), np.isinf(ref)), (prof, ref)
    ok = np.isfinite(ref)
    assert (prof[ok] >= ref[ok] - 1e-3).all() and (prof[ok] <= 1.02 * ref[ok] + 1e-3).all(), (prof, ref)


def test_combination_orients_by_the_dominant_entry_and_keeps_entries_at_tol():
    """Documented: sign fixed so the largest |entry| is positive, terms by decreasing |entry|, kept where
    |entry| ≥ tol (0.1 is kept, 0.09 dropped); ``log `` only for scale="log"."""
    from lightfit.inference.identifiability import combination

    assert combination([-0.8, 0.6, 0.1, 0.09], ("a", "b", "c", "d")) == "+0.80 log a -0.60 log b -0.10 log c"
    assert combination([0.3, -0.9], ("a", "b"), scale="natural") == "+0.90 b -0.30 a"


def test_fisher_of_a_linear_two_parameter_model_against_its_closed_form():
    """r(x) = J x with J = [[1, 1], [1, 0], [0, 1]]: F = JᵀJ = [[2, 1], [1, 2]], eigenvalues 3 (along
    (1, 1)/√2, the stiff one) and 1 (along (1, −1)/√2), 1σ widths 1/√3 and 1."""
    import jax.numpy as jnp

    from lightfit.inference.identifiability import fisher_information

    J = np.array([[1.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
    fi = fisher_information(lambda x: jnp.asarray(J) @ x, np.array([0.4, -2.0]), ("p", "q"), scale="natural")
    np.testing.assert_allclose(fi.fisher, [[2.0, 1.0], [1.0, 2.0]], rtol=1e-12)
    np.testing.assert_allclose(fi.eigenvalues, [3.0, 1.0], rtol=1e-12)
    np.testing.assert_allclose(fi.widths, [3**-0.5, 1.0], rtol=1e-12)
    assert fi.stiff == "+0.71 p +0.71 q" and fi.sloppy == "+0.71 p -0.71 q"
    rows = fi.table()
    assert [r["width_scale"] for r in rows] == ["natural", "natural"]
    np.testing.assert_allclose([r["width_1sigma"] for r in rows], [3**-0.5, 1.0], rtol=1e-12)


def test_profile_offsets_are_along_the_unit_direction():
    """A direction of any length is normalised: the slice of ½ xᵀHx at offset t along d = (2, −4) is
    ½ t² d̂ᵀHd̂ with d̂ = d/|d| (not ½ t² dᵀHd, 20× larger)."""
    import jax.numpy as jnp

    H = np.array([[4.0, 1.9], [1.9, 1.0]])
    d = np.array([2.0, -4.0])
    dh = d / np.sqrt(20.0)
    ts = np.linspace(-1, 1, 5)
    _, prof, slc = profile_likelihood(lambda x: 0.5 * x @ jnp.asarray(H) @ x, np.zeros(2), d, ts, scale="natural")
    np.testing.assert_allclose(slc, 0.5 * ts**2 * (dh @ H @ dh), rtol=1e-10)
    np.testing.assert_allclose(prof, ts**2 / (2 * (dh @ np.linalg.solve(H, dh))), atol=1e-7)


def test_profile_in_log_coordinates_moves_the_log_of_the_parameters():
    """scale="log": offsets t are in log x. nll = (log x₀ − log 2)² + (log x₁)² through x̂ = (2, 3)
    along (1, 0): the slice is t² + (log 3)², the profile (x₁ optimised to 1) t²."""
    import jax.numpy as jnp

    ts = np.array([-0.5, 0.0, 0.3, 0.8])
    _, prof, slc = profile_likelihood(
        lambda x: (jnp.log(x[0]) - np.log(2.0)) ** 2 + jnp.log(x[1]) ** 2,
        np.array([2.0, 3.0]),
        np.array([1.0, 0.0]),
        ts,
        scale="log",
    )
    np.testing.assert_allclose(slc, ts**2 + np.log(3.0) ** 2, rtol=1e-10)
    np.testing.assert_allclose(prof, ts**2, atol=1e-8)


def test_the_table_pairs_each_eigenvalue_with_its_own_eigenvector_and_a_blind_parameter_is_unbounded():
    """r(x) = (p, 3q, 2r), s unused: F = diag(1, 9, 4, 0) by hand, so the stiff-to-sloppy order is q
    (λ 9, width 1/3), r (λ 4, width 1/2), p (λ 1, width 1), s (λ 0 exactly, the data say nothing:
    width ∞, not 1/√1e-300). The eigenvector matrix is a permutation that is not symmetric, so a
    table reading eigenvectors' rows instead of columns names the wrong parameter."""
    import jax.numpy as jnp

    from lightfit.inference.identifiability import fisher_information

    fi = fisher_information(
        lambda x: jnp.stack([x[0], 3.0 * x[1], 2.0 * x[2]]), np.ones(4), ("p", "q", "r", "s"), scale="natural"
    )
    rows = fi.table()
    assert [r["combination"] for r in rows] == ["+1.00 q", "+1.00 r", "+1.00 p", "+1.00 s"]
    np.testing.assert_allclose([r["eigenvalue"] for r in rows], [9.0, 4.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose([r["width_1sigma"] for r in rows[:3]], [1 / 3, 1 / 2, 1.0], rtol=1e-12)
    assert rows[3]["width_1sigma"] == np.inf and fi.widths[3] == np.inf
    assert fi.stiff == "+1.00 q" and fi.sloppy == "+1.00 s"


def test_fisher_refuses_a_zero_in_log_coordinates_and_a_wrong_number_of_values():
    """scale="log" differentiates with respect to log x, undefined at x = 0 (it would give NaN
    eigenvectors, not an error); and one value per name, or the names would be paired with the
    wrong entries of the eigenvectors (zip truncates silently)."""
    import jax.numpy as jnp
    import pytest

    from lightfit.errors import InputError
    from lightfit.inference.identifiability import fisher_information

    with pytest.raises(InputError, match="non-positive"):
        fisher_information(lambda x: x * 2.0, np.array([1.0, 0.0]), ("a", "b"), scale="log")
    with pytest.raises(InputError, match="x0 shape"):
        fisher_information(lambda x: jnp.asarray(x), np.array([1.0, 2.0, 3.0]), ("a", "b"), scale="natural")
    # a residual that is NaN at x0 (an unconverged photosynthesis) gave NaN eigenvalues unsaid (a review)
    nan_row = lambda x: jnp.stack([x[0] * 2.0, jnp.sqrt(x[1] - 3.0), x[0] + x[1]])  # noqa: E731
    with pytest.raises(InputError, match=r"x0=\[1.0, 2.0\] is not finite with respect to \['b'\]"):
        fisher_information(nan_row, np.array([1.0, 2.0]), ("a", "b"), scale="natural")
    assert fisher_information(nan_row, np.array([1.0, 4.0]), ("a", "b"), scale="natural").eigenvalues.all()


def test_the_profile_never_exceeds_the_slice_even_from_a_trapped_warm_start():
    """A profile is a minimum over the other directions, and the slice (w = 0) is one candidate, so
    profile ≤ slice at every offset. nll = 4y²(y − 1)² + (1 − x)(y − 1)² + ¼xy² through (0, 0) along
    x: at x = 0 the only minimum is y = 1 (the slice y = 0 is worse), at x = ½ the only one is near
    y = 1, at x = 1 (∂/∂y = y(16y² − 24y + 8.5): wells at y = 0 and y ≈ 0.93) the warm start from
    y ≈ 1 lands in the local well (≈ 0.23) while the global minimum is y = 0, value 0, on the slice.
    Reference: a brute-force grid over y."""
    ts = np.array([0.0, 0.5, 1.0])
    _, prof, slc = profile_likelihood(
        lambda x: 4 * x[1] ** 2 * (x[1] - 1) ** 2 + (1 - x[0]) * (x[1] - 1) ** 2 + 0.25 * x[0] * x[1] ** 2,
        np.zeros(2),
        np.array([1.0, 0.0]),
        ts,
        scale="natural",
    )
    y = np.linspace(-2.0, 3.0, 500_001)
    brute = [np.min(4 * y**2 * (y - 1) ** 2 + (1 - t) * (y - 1) ** 2 + 0.25 * t * y**2) for t in ts]
    assert np.all(prof <= slc + 1e-12), (prof, slc)
    np.testing.assert_allclose(prof, brute, atol=1e-8)


def test_profile_of_a_nonlinear_model_against_a_brute_force_scalar_minimisation():
    """m(τ) = a·exp(−kτ), Gaussian nll, profiled along a (k optimised) in natural and log coordinates:
    each profile value is compared with scipy's bounded scalar minimisation over k at that a (not the
    module's BFGS), to 1e-9 in nll, so an optimiser stopped early (a loose gradient tolerance leaves
    errors ~4e-6 here: the inner problem is not quadratic) is caught."""
    import jax.numpy as jnp
    from scipy.optimize import minimize_scalar

    tau = np.linspace(0.0, 3.0, 8)
    y = 2.0 * np.exp(-0.7 * tau) + 0.05 * np.array([1.0, -1.0, 0.5, 0.3, -0.8, 0.2, -0.1, 0.6])

    sigma = 1.0  # a shallow inner problem: an optimiser stopped early is far from its minimum

    def nll_np(a, k):
        return 0.5 * np.sum(((y - a * np.exp(-k * tau)) / sigma) ** 2)

    x_hat = np.array([2.0, 0.7])
    ts = np.array([-0.3, -0.15, 0.0, 0.15, 0.3])
    for scale, amplitudes in (("natural", x_hat[0] + ts), ("log", x_hat[0] * np.exp(ts))):
        _, prof, _ = profile_likelihood(
            lambda x: 0.5 * jnp.sum(((y - x[0] * jnp.exp(-x[1] * tau)) / sigma) ** 2),
            x_hat,
            np.array([1.0, 0.0]),
            ts,
            scale=scale,
        )
        ref = [
            minimize_scalar(
                lambda k, a=a: nll_np(a, k), bounds=(0.01, 5.0), method="bounded", options={"xatol": 1e-12}
            ).fun
            for a in amplitudes
        ]
        np.testing.assert_allclose(prof, ref, atol=1e-9, err_msg=scale)


@pytest.mark.parametrize("scale", ["natural", "log"])
def test_offsets_in_box_span_the_boxs_corners_along_the_direction(scale):
    """The offsets whose hyperplane meets the box run from the lowest to the highest corner's
    d·(u − û): against every corner of the box enumerated, and a bound at ±∞ (or 0 in log) leaving
    the side it bounds open unless the direction has no component there."""
    import itertools

    from lightfit.inference.identifiability import offsets_in_box

    rng = np.random.default_rng(3)
    lo, hi = np.array([0.2, 0.5, 1.0]), np.array([0.9, 2.0, 3.0])
    u = np.log if scale == "log" else (lambda v: v)
    for _ in range(5):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        x_hat = rng.uniform(lo, hi)
        along = [d @ (u(np.array(c)) - u(x_hat)) for c in itertools.product(*zip(lo, hi, strict=True))]
        assert offsets_in_box(x_hat, d, (lo, hi), scale) == pytest.approx((min(along), max(along)), abs=1e-12)
    open_lo = (np.array([0.0 if scale == "log" else -np.inf, 0.5]), np.array([1.0, 2.0]))
    t_lo, t_hi = offsets_in_box(np.array([0.5, 1.0]), np.array([1.0, 1.0]), open_lo, scale)
    assert t_lo == -np.inf and np.isfinite(t_hi)
    t_lo, t_hi = offsets_in_box(np.array([0.5, 1.0]), np.array([0.0, 1.0]), open_lo, scale)  # x₀ not along d
    assert (t_lo, t_hi) == pytest.approx((u(0.5) - u(1.0), u(2.0) - u(1.0)))


def test_the_profile_slides_along_a_face_of_the_box_to_its_minimum():
    """nll = 5(x − 2)² + 50(y − 0.2 − 0.9(x − ½))² + (z − ½)², box [0, 1]³, profiled along z through
    (½, ½, ½): the minimum over (x, y) lies on the face x = 1 (y = 0.65), value 5 + (z − ½)². BFGS
    against the +∞ outside stopped where it met the face (12.53 at z = ½, 6.35 at z = ½ ± 0.2); on a
    real run (quick field, emulated light) up to 7 nll units above scipy's constrained minimum."""
    ts = np.array([-0.2, 0.0, 0.2])
    _, prof, _ = profile_likelihood(
        lambda x: 5 * (x[0] - 2.0) ** 2 + 50 * (x[1] - 0.2 - 0.9 * (x[0] - 0.5)) ** 2 + (x[2] - 0.5) ** 2,
        np.full(3, 0.5),
        np.array([0.0, 0.0, 1.0]),
        ts,
        scale="natural",
        box=(np.zeros(3), np.ones(3)),
    )
    np.testing.assert_allclose(prof, 5.0 + ts**2, atol=1e-6)


@pytest.mark.parametrize(
    ("kw", "parameter"),
    [
        ({"scale": "LOG"}, "scale"),  # was taken for "natural" without a word
        ({"direction": [0.0, 0.0]}, "direction"),  # a profile of NaN
        ({"direction": [1.0, 0.0, 0.0]}, "direction"),  # JAX's broadcast TypeError
        ({"x_hat": [np.nan, 1.0]}, "x_hat"),
        ({"x_hat": [0.0, 1.0], "scale": "log"}, "x_hat"),
        ({"ts": [0.0, np.nan]}, "ts"),  # a profile of NaN
    ],
)
def test_the_profile_refuses_a_line_it_cannot_follow_by_name(kw, parameter):
    from lightfit.errors import InputError

    args = {"x_hat": [1.0, 1.0], "direction": [1.0, 0.0], "ts": [0.0, 0.1], "scale": "natural"} | kw
    with pytest.raises(InputError) as e:
        profile_likelihood(lambda x: (x**2).sum(), args["x_hat"], args["direction"], args["ts"], scale=args["scale"])
    assert e.value.parameter == parameter
    if parameter in ("scale", "direction", "x_hat"):
        with pytest.raises(InputError) as e:
            offsets_in_box(args["x_hat"], args["direction"], (0.0, 2.0), scale=args["scale"])
        assert e.value.parameter == parameter


@pytest.mark.parametrize("scale", ["log", "natural"])
def test_fisher_refuses_a_value_that_is_not_finite(scale):
    """NaN passed the log scale's "> 0" test (NaN ≤ 0 is False), and the natural scale took it as
    given: a Fisher matrix and eigenvalues of NaN, unsaid."""
    from lightfit.errors import InputError
    from lightfit.inference.identifiability import fisher_information

    with pytest.raises(InputError, match=r"non-finite value\(s\) of \['b'\]") as e:
        fisher_information(lambda x: x * 2.0, np.array([1.0, np.nan]), ("a", "b"), scale=scale)
    assert e.value.parameter == "x0"


def test_a_product_model_is_singular_and_its_sloppy_eigenvector_points_as_its_combination_reads():
    """y = a·b·x fixes only the product: by hand in log coordinates ∂r/∂log a = ∂r/∂log b = −a·b·x/σ, so
    F = S·[[1, 1], [1, 1]] with S = Σ(a·b·x/σ)² (checked against central differences), eigenvalues 2S and 0,
    the null direction (1, −1)/√2 in log space, (a, −b)/‖(a, −b)‖ in natural space. The eigenvector is the
    one stored as the profile's direction, beside the combination's string: it must point as the string
    reads (eigh returned (−0.71, +0.71) here, the profile's offset axis then ran against its label)."""
    import jax.numpy as jnp

    from lightfit.inference.identifiability import fisher_information

    x, sigma, a, b = np.linspace(0.1, 2.0, 20), 0.05, 2.0, 0.5
    y = a * b * x

    def residuals(p):
        return (y - p[0] * p[1] * jnp.asarray(x)) / sigma

    s = np.sum((a * b * x / sigma) ** 2)
    h, lx = 1e-5, np.log([a, b])
    jac = np.column_stack(
        [
            (np.asarray(residuals(np.exp(lx + h * e))) - np.asarray(residuals(np.exp(lx - h * e)))) / (2 * h)
            for e in np.eye(2)
        ]
    )
    fi = fisher_information(residuals, [a, b], ("a", "b"), scale="log")
    np.testing.assert_allclose(fi.fisher, jac.T @ jac, rtol=1e-6)
    np.testing.assert_allclose(fi.fisher, s * np.ones((2, 2)), rtol=1e-10)
    np.testing.assert_allclose(fi.eigenvalues, [2 * s, 0.0], atol=1e-8 * s)
    assert fi.sloppy == "+0.71 log a -0.71 log b" and fi.widths[-1] > 1e3
    np.testing.assert_allclose(fi.eigenvectors[:, -1], np.array([1.0, -1.0]) / np.sqrt(2), atol=1e-10)
    np.testing.assert_allclose(fi.eigenvectors[:, 0], np.array([1.0, 1.0]) / np.sqrt(2), atol=1e-10)
    nat = fisher_information(residuals, [a, b], ("a", "b"), scale="natural")
    assert nat.sloppy == "+0.97 a -0.24 b"
    np.testing.assert_allclose(nat.eigenvectors[:, -1], np.array([a, -b]) / np.hypot(a, b), atol=1e-10)
    # the profile of a along the null direction is flat (b follows a), the slice is not
    ts, prof, slc = profile_likelihood(lambda p: 0.5 * jnp.sum(residuals(p) ** 2), [a, b], [1.0, 0.0], [-0.5, 0.5])
    np.testing.assert_allclose(prof, 0.0, atol=1e-8)
    assert np.all(slc > 100.0)


def test_a_parameter_the_residuals_ignore_has_eigenvalue_zero_whatever_the_round_off():
    """r = J x with J's column of s all zero: F has a zero row and column, so s's eigenvalue is 0 exactly
    and its width ∞ (the data say nothing of it); the others are those of F without s. eigh returned
    ±1e-16…1e-14 there (19 of these 40 matrices positive), a finite width of ~10⁷ instead: unbounded or
    not by chance of the round-off's sign."""
    import jax.numpy as jnp

    from lightfit.inference.identifiability import fisher_information

    rng = np.random.default_rng(0)
    names = ("p", "q", "s", "r", "u")
    for _ in range(40):
        jac = rng.standard_normal((54, 5)) * np.array([300.0, 60.0, 1.0, 0.3, 0.1])
        jac[:, 2] = 0.0
        fi = fisher_information(lambda x, j=jac: jnp.asarray(j) @ x, np.ones(5), names, "natural")
        assert fi.eigenvalues[-1] == 0.0 and fi.widths[-1] == np.inf and fi.sloppy == "+1.00 s"
        rest = np.delete(jac, 2, axis=1)
        np.testing.assert_allclose(fi.eigenvalues[:4], np.linalg.eigvalsh(rest.T @ rest)[::-1], rtol=1e-9)
