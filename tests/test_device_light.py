"""The GPU check's packing (benchmarks/device_light.py): the wheels carried to the device keep
exactly the variants lightfit picks and a RECORD that lists what is left.

The device machine has no network and takes 64 MiB per call, so a wheel that kept a variant too
many (as a prefix match once did with ``*_mono_polarized``) or lost one lightfit needs would be
found only there, in a session's scarce device time.
"""

from __future__ import annotations

import zipfile


def test_stripped_wheel_keeps_the_two_variants_and_a_matching_record(tmp_path, script_module):
    dl = script_module("device_light")
    ext = ".cpython-312-x86_64-linux-gnu.so"
    members = [
        *(f"mitsuba/{v}{ext}" for v in ("cuda_ad_mono", "llvm_ad_mono", "cuda_ad_mono_polarized")),
        *(f"mitsuba/{v}{ext}" for v in ("llvm_ad_rgb", "scalar_rgb", "cuda_ad_spectral")),
        f"mitsuba/mitsuba_ext{ext}",
        "mitsuba/libmitsuba.so",
        "mitsuba/plugins/path.so",
        "mitsuba/plugins/perspective.so",
        "mitsuba/plugins/volpath.so",
        "mitsuba/data/srgb.coeff",
        "mitsuba/data/ior/Au.eta.spd",
        "mitsuba/include/mitsuba/mitsuba.h",
        "mitsuba/__init__.py",
    ]
    record = "mitsuba-3.9.1.dist-info/RECORD"
    src, dst = tmp_path / "in.whl", tmp_path / "out.whl"
    with zipfile.ZipFile(src, "w") as z:
        for name in members:
            z.writestr(name, name)
        z.writestr(record, "".join(f"{n},sha256=x,1\n" for n in [*members, record]))
    dl._strip_wheel(src, dst)
    with zipfile.ZipFile(dst) as z:
        kept = set(z.namelist())
        listed = {line.split(",", 1)[0] for line in z.read(record).decode().splitlines() if line}
        assert z.read("mitsuba/plugins/path.so") == b"mitsuba/plugins/path.so"
    assert kept == {
        f"mitsuba/cuda_ad_mono{ext}",
        f"mitsuba/llvm_ad_mono{ext}",
        f"mitsuba/mitsuba_ext{ext}",
        "mitsuba/libmitsuba.so",
        "mitsuba/plugins/path.so",
        "mitsuba/plugins/perspective.so",
        "mitsuba/data/ior/Au.eta.spd",
        "mitsuba/__init__.py",
        record,
    }
    assert listed == kept
