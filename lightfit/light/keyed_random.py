"""Keyed random numbers: every random number of a render is a pure function of (seed, key, dimension).

No generator state is carried between calls, so any subset of the numbers can be computed in any
order, on any thread or in any pass, and a render's bits depend on its seed alone (same seed, same
bits; a segment's numbers do not depend on which other segments are requested). Three hashes do
this, each where its numbers are made:

* :func:`keyed_uniforms` (numpy, 64-bit): the per-(segment, replicate) shifts of the paths'
  randomised quasi-Monte Carlo points, set up once per estimator (SplitMix64's finaliser, Steele,
  Lea & Flood 2014, *OOPSLA*, doi:10.1145/2660193.2660195).
* :func:`hash32` (Dr.Jit ``UInt32``): the paths' hashed dimensions per point, inside the
  sampling kernel (Wellons' "lowbias32", 2018, a 32-bit integer hash with full avalanche).
* :func:`random_bits` (Dr.Jit ``UInt32``): the projection's per-ray and per-replicate words
  (Mitsuba's ``sample_tea_32``, the Tiny Encryption Algorithm, Wheeler & Needham 1994, at
  :data:`TEA_ROUNDS` rounds; Zafar, Olano & Curtis 2010, *I3D*, use it as a GPU random number
  generator and show that few rounds do not decorrelate neighbouring inputs).

Each is tested for independence of consecutive keys, seeds and replicates by a χ² test of pairs
(``tests/test_keyed_random.py``). Changing any of them moves every render's bits within Monte Carlo
error (and ``PROJECTION_VERSION`` for the projection's).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from lightfit.errors import check_integer

#: Rounds of the TEA hash that turn a ray's or replicate's index and a key into its random bits
#: (:func:`random_bits`). Mitsuba's default of 4 does not mix consecutive indices: the per-replicate
#: sky shifts of replicates 0–3 correlated up to 0.46 and neighbouring cells' jitters were far from
#: independent (χ² of 200 000 consecutive pairs 2.7 × 10⁵ for 99 degrees of freedom), so the
#: replicates were not independent and the sky's reported SE fell short of the seeds' spread (≈ 3 %
#: in variance over the 100-plant cell's segments, ``benchmarks/bench_se_calibration.py``; 5–9 % for
#: the sky part on a small cell). 16 rounds pass the same checks (docs/light-sampling.md, "Are the reported
#: standard errors right?").
TEA_ROUNDS = 16


#: Seeds are distinct below this: :func:`random_bits` hashes the seed in 32 bits.
SEED_LIMIT = 2**32


def check_seed(seed, column: str = "seed") -> int:
    """A render's seed: an integer in [0, 2³²) (Python or numpy, not a bool). Larger seeds would
    repeat smaller ones' random numbers (the hashes take the seed modulo 2³² or 2⁶⁴), and a float
    seed would be rounded."""
    return check_integer(seed, "seed", 0, high=SEED_LIMIT, column=column, expected="an integer in [0, 2³²)")


def keyed_uniforms(seed: int, keys: np.ndarray, dims: ArrayLike) -> np.ndarray:
    """Uniform [0, 1) numbers, shape ``keys.shape + (len(dims),)``, a pure function of (seed, key, dim).

    SplitMix64 finaliser (Steele et al. 2014) over ``seed``, the 64-bit key and the dimension:
    each dimension's numbers are the same whichever others are computed with it.
    """

    def mix(z):
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))

    golden = np.uint64(0x9E3779B97F4A7C15)
    out = np.empty(keys.shape + (len(dims),))
    with np.errstate(over="ignore"):  # modular 64-bit arithmetic is the point
        # int(): a numpy integer seed (check_seed accepts them) % 2**64 overflowed numpy's int64.
        base = mix(keys.astype(np.uint64) * golden + mix(np.uint64(int(seed) % 2**64) + np.uint64(1)))
        # One dimension at a time: temporaries of the keys' size, not of keys × dims.
        for i, d in enumerate(np.asarray(dims, dtype=np.uint64)):
            z = mix(base + (d + np.uint64(1)) * golden)
            # 24 bits: exactly representable in float32, and strictly below 1.
            out[..., i] = (z >> np.uint64(40)).astype(np.float64) * (1.0 / 2**24)
    return out


def hash32(x):
    """A 32-bit integer hash (Wellons' lowbias32) of Dr.Jit UInt32 ``x``: full avalanche."""
    x = x ^ (x >> 16)
    x = x * 0x7FEB352D
    x = x ^ (x >> 15)
    x = x * 0x846CA68B
    return x ^ (x >> 16)


def random_bits(mi, index, seed: int, kind: str, dim: int):
    """Two independent uniform 32-bit words per entry of ``index`` (a ray's or a replicate's, a
    ``mi.UInt32``), for the random dimension ``dim`` of ``kind``'s ("sun" or "sky") rays at ``seed``:
    :data:`TEA_ROUNDS` rounds of TEA keyed by the three."""
    import drjit as dr

    k = (int(seed) * 0x9E3779B1 + {"sun": 1, "sky": 2}[kind] * 0x85EBCA77 + dim * 0xC2B2AE3D) % 2**32
    return mi.sample_tea_32(index, dr.opaque(mi.UInt32, k), TEA_ROUNDS)
