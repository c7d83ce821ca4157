"""Profile likelihood where only part of the line is allowed (lightfit.inference.identifiability)."""

from __future__ import annotations

import numpy as np

from lightfit.inference.identifiability import profile_likelihood


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
        allowed=lambda x: (x[0] >= 0.5) & (x[0] <= 1.5),
    )
    x0 = 1.0 + ts
    np.testing.assert_allclose(slc, (x0 - 3.0) ** 2, rtol=1e-12)  # the slice goes wherever the line goes
    inside = (x0 >= 0.5) & (x0 <= 1.5)
    np.testing.assert_allclose(prof[inside], (x0[inside] - 3.0) ** 2, atol=1e-9)
    assert np.all(prof[~inside] == np.inf), prof


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
