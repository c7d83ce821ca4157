"""The render's keyed random numbers (lightfit/light/keyed_random.py): pure functions of (seed, key,
dimension) whose neighbours are independent.

Independence is checked with the χ² statistic of the 10 × 10 histogram of pairs (u_a, u_b) of
uniforms that a render puts side by side: consecutive keys (neighbouring segments, points, rays),
consecutive seeds, neighbouring dimensions. 99 degrees of freedom if the pairs are independent;
the bound 160 is exceeded with probability ≈ 10⁻⁴. Each test also shows that a weak hash of the
same inputs fails it, so that the check can fail.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from lightfit.light import keyed_random
from lightfit.light.backend import mitsuba
from lightfit.light.keyed_random import hash32, keyed_uniforms

BOUND = chi2.ppf(1 - 1e-4, 99)


def _pair_chi2(a: np.ndarray, b: np.ndarray) -> float:
    """χ² of the 10 × 10 histogram of pairs of uniforms (99 degrees of freedom if independent)."""
    h, _, _ = np.histogram2d(a, b, 10, range=[[0, 1], [0, 1]])
    e = len(a) / 100
    return float(((h - e) ** 2 / e).sum())


def test_keyed_uniforms_for_some_dimensions_are_those_of_all():
    """Computing only the dimensions the paths read leaves each one's numbers as they were."""
    keys = np.arange(12, dtype=np.uint64).reshape(3, 4)
    full = keyed_uniforms(7, keys, np.arange(10))
    some = keyed_uniforms(7, keys, np.array([1, 4, 7]))
    assert some.shape == (3, 4, 3)
    np.testing.assert_array_equal(some, full[..., [1, 4, 7]])
    assert 0.0 <= full.min() and full.max() < 1.0 and len(np.unique(full)) == full.size


def test_keyed_uniforms_of_neighbouring_keys_seeds_and_dimensions_are_independent():
    """The paths' per-(segment, replicate) shifts: consecutive keys, consecutive seeds and
    neighbouring dimensions give independent pairs. The finaliser left out (the keys times the
    golden ratio alone, a Weyl sequence) fails the same test."""
    keys = np.arange(100_001, dtype=np.uint64)
    u = keyed_uniforms(7, keys, [0, 1])
    by_seed = np.stack([keyed_uniforms(s, keys[:20_000], [3])[:, 0] for s in (41, 42)])
    stats = [_pair_chi2(u[:-1, 0], u[1:, 0]), _pair_chi2(u[:, 0], u[:, 1]), _pair_chi2(*by_seed)]
    assert max(stats) < BOUND, stats
    with np.errstate(over="ignore"):
        weyl = ((keys * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(40)).astype(np.float64) / 2**24
    assert _pair_chi2(weyl[:-1], weyl[1:]) > 10 * BOUND


@pytest.mark.parametrize("key", [0, 12_345, 2**24 - 1])
def test_hashed_dimensions_of_consecutive_points_are_independent(key):
    """The paths' hashed dimensions (``SegmentEstimator``'s sampling kernel): for a replicate's key
    (its 24-bit shift), hash32(hash32(key + dim·φ) + j) over consecutive points j, and between
    neighbouring dimensions at the same point, are independent. One multiplicative hash (no
    xor-shifts) fails it."""
    mi = mitsuba()
    j = mi.UInt32(np.arange(100_001, dtype=np.uint32))

    def word(dim, h=hash32):
        return np.asarray(h(h(mi.UInt32(key + (dim * 0x9E3779B9) % 2**32)) + j), np.float64) / 2**32

    u0, u1 = word(5), word(6)
    stats = [_pair_chi2(u0[:-1], u0[1:]), _pair_chi2(u0, u1)]
    assert max(stats) < BOUND, stats
    weak = word(5, h=lambda x: x * 0x9E3779B9)
    assert _pair_chi2(weak[:-1], weak[1:]) > 10 * BOUND


def test_random_bits_of_consecutive_indices_and_replicates_are_independent(monkeypatch):
    """The projection's random words: consecutive ray indices (neighbouring grid cells, one seed)
    and the replicate shifts of replicates 0 and 1 (over 5 000 seeds) give independent pairs.
    Mitsuba's default 4 rounds of TEA fails both by orders of magnitude (measured 2.7 × 10⁵ and
    6.6 × 10³): its replicates were correlated."""
    mi = mitsuba()

    def stats():
        idx = mi.UInt32(np.arange(200_001, dtype=np.uint32))
        u = np.asarray(keyed_random.random_bits(mi, idx, 7, "sun", 0)[0], np.float64) / 2**32
        seeds = range(5_000)
        shift = [
            np.array([int(keyed_random.random_bits(mi, mi.UInt32(rep), s, "sky", 1)[0][0]) for s in seeds]) / 2**32
            for rep in (0, 1)
        ]
        return _pair_chi2(u[:-1], u[1:]), _pair_chi2(*shift)

    assert max(stats()) < BOUND, stats()
    monkeypatch.setattr(keyed_random, "TEA_ROUNDS", 4)
    assert min(stats()) > 10 * BOUND


def test_random_bits_of_each_kind_and_dimension_at_one_index_are_independent():
    """The projection draws, for one ray index, words of both kinds (sun, sky) and of its dimensions
    (0: jitter, 1: replicate shift, 2–3: scattering, 4: roulette) side by side: pairs across kinds,
    across dimensions and the two words of one draw must be independent."""
    mi = mitsuba()
    idx = mi.UInt32(np.arange(100_000, dtype=np.uint32))

    def u(kind, dim, word=0):
        return np.asarray(keyed_random.random_bits(mi, idx, 7, kind, dim)[word], np.float64) / 2**32

    pairs = [
        (u("sun", 0), u("sky", 0)),
        (u("sun", 0), u("sun", 1)),
        (u("sky", 2), u("sky", 4)),
        (u("sky", 3), u("sun", 2)),
        (u("sun", 0), u("sun", 0, 1)),
    ]
    stats = [_pair_chi2(a, b) for a, b in pairs]
    assert max(stats) < BOUND, stats


def _tea_decrypt(w0: np.ndarray, w1: np.ndarray, rounds: int):
    """Inverse of Mitsuba's ``sample_tea_32``: TEA (Wheeler & Needham 1994) with the key words of
    Zafar, Olano & Curtis (2010), run backwards, in numpy uint32 arithmetic."""
    k0, k1, k2, k3 = (np.uint32(x) for x in (0xA341316C, 0xC8013EA4, 0xAD90777D, 0x7E95761E))
    four, five = np.uint32(4), np.uint32(5)
    v0, v1 = w0.astype(np.uint32), w1.astype(np.uint32)
    for r in range(rounds, 0, -1):
        s = np.uint32(r * 0x9E3779B9 % 2**32)
        v1 = v1 - (((v0 << four) + k2) ^ (v0 + s) ^ ((v0 >> five) + k3))
        v0 = v0 - (((v1 << four) + k0) ^ (v1 + s) ^ ((v1 >> five) + k1))
    return v0, v1


def test_random_bits_are_sixteen_rounds_of_tea_of_the_index_under_one_key_per_stream():
    """Decrypting a stream's words with 16 rounds of TEA gives back the ray index and one constant
    word: the 16 rounds the independence checks were made at (TEA_ROUNDS), and a key of its own for
    every seed, kind and dimension (words of two streams never coincide)."""
    mi = mitsuba()
    idx = np.arange(0, 2**32 - 1, 858_993, dtype=np.uint32)  # ≈ 5 000 indices over the whole range
    keys = {}
    for seed in (7, 8):
        for kind in ("sun", "sky"):
            for dim in range(5):
                words = keyed_random.random_bits(mi, mi.UInt32(idx), seed, kind, dim)
                v0, v1 = _tea_decrypt(*(np.asarray(w, dtype=np.uint32) for w in words), 16)
                np.testing.assert_array_equal(v0, idx)
                assert (v1 == v1[0]).all(), (seed, kind, dim)
                keys[seed, kind, dim] = int(v1[0])
    assert len(set(keys.values())) == len(keys), keys


def _splitmix_reference(seed: int, key: int, dim: int) -> float:
    """keyed_uniforms' number in Python integers: the SplitMix64 finaliser (Steele et al. 2014)
    over seed, key and dimension, mod 2⁶⁴, its top 24 bits."""
    m = 2**64

    def mix(z):
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) % m
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) % m
        return z ^ (z >> 31)

    g = 0x9E3779B97F4A7C15
    base = mix((key * g + mix((seed + 1) % m)) % m)
    return (mix((base + (dim + 1) * g) % m) >> 40) / 2**24


@pytest.mark.parametrize("seed", [0, 7, 2**32 - 1, np.int64(7), np.uint32(2**32 - 1), np.uint64(3)])
def test_keyed_uniforms_are_splitmix64_for_python_and_numpy_seeds(seed):
    """check_seed accepts numpy integers; keyed_uniforms raised OverflowError on them (``seed %
    2**64`` in numpy's int64). Values against a Python-integer transcription, seeds up to 2³² − 1."""
    keys = np.array([0, 1, 255, 256, (12_345 << 8) + 7, (1 << 48) + 3], dtype=np.uint64)
    got = keyed_uniforms(seed, keys, [0, 4, 37])
    ref = [[_splitmix_reference(int(seed), int(k), d) for d in (0, 4, 37)] for k in keys]
    np.testing.assert_array_equal(got, ref)
