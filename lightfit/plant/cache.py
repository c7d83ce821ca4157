"""On-disk cache of grown plants, keyed by (parameter file content, dates, seed, versions).

Entries are ``.npz`` files written atomically (temp file + rename). Each stores its own key
and a SHA-256 of its payload; an entry whose key, checksum or schema does not match — a
truncated write, a file from another lightfit version, bit rot — is reported, rebuilt and
overwritten, never used.
"""

from __future__ import annotations

import hashlib
import io
import logging
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.cache import cache_root
from lightfit.files import load_npz, replaced
from lightfit.plant.growth import ORGAN_CATEGORIES, GrowthConfig, grow_plant

log = logging.getLogger(__name__)
#: Bump when the segment table layout changes: older entries become stale.
SCHEMA = 1


def cache_dir() -> Path:
    """``$LIGHTFIT_CACHE/plants`` or ``~/.cache/lightfit/plants``."""
    return cache_root() / "plants"


def cache_key(config: GrowthConfig, seed: int) -> str:
    return hashlib.sha256(f"{config.fingerprint()}|seed={int(seed)}|schema={SCHEMA}".encode()).hexdigest()[:32]


def _payload_digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(name.encode())
        h.update(str(a.dtype).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _to_arrays(df: pd.DataFrame) -> dict[str, np.ndarray]:
    out = {}
    for c in df.columns:
        v = df[c]
        out[c] = v.astype(str).to_numpy().astype("U8") if isinstance(v.dtype, pd.CategoricalDtype) else v.to_numpy()
    return out


def _from_arrays(arrays: dict[str, np.ndarray], columns: list[str]) -> pd.DataFrame:
    df = pd.DataFrame({c: arrays[c] for c in columns})
    df["organ_type"] = pd.Categorical(df["organ_type"], categories=ORGAN_CATEGORIES)
    return df


def load_or_grow(
    config: GrowthConfig, seed: int, plant_id: int = 0, *, directory: Path | None = None
) -> tuple[pd.DataFrame, bool]:
    """The plant grown from ``seed``: from the cache if a valid entry exists, else simulated and stored.

    Returns (segment table with ``plant_id`` set, whether it came from the cache).
    """
    directory = Path(directory or cache_dir())
    key = cache_key(config, seed)
    path = directory / f"{key}.npz"
    if path.exists():
        try:
            with load_npz(path, allow_pickle=False) as z:
                meta = {k: str(z[k]) for k in ("_key", "_digest", "_columns")}
                arrays = {k: z[k] for k in z.files if not k.startswith("_")}
            columns = meta["_columns"].split(",")
            if meta["_key"] != key or _payload_digest(arrays) != meta["_digest"] or set(columns) != set(arrays):
                raise ValueError("key, checksum or columns do not match")
            df = _from_arrays(arrays, columns)
            return _with_plant_id(df, plant_id), True
        except Exception as err:  # noqa: BLE001 - any unreadable entry is rebuilt
            log.warning("plant cache entry %s is corrupt or stale (%s); rebuilding", path, err)
    df = grow_plant(config, seed, plant_id=0)
    arrays = _to_arrays(df)
    directory.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez_compressed(buf, _key=key, _digest=_payload_digest(arrays), _columns=",".join(df.columns), **arrays)
    with replaced(path) as tmp:  # per process: concurrent workers growing one plant never share a file
        tmp.write_bytes(buf.getvalue())
    return _with_plant_id(df, plant_id), False


def _with_plant_id(df: pd.DataFrame, plant_id: int) -> pd.DataFrame:
    from lightfit.plant.growth import SEGMENT_ID_STRIDE

    df = df.copy()
    df["plant_id"] = np.int64(plant_id)
    df["segment_id"] = plant_id * SEGMENT_ID_STRIDE + df["segment_index"].to_numpy()
    return df
