"""Tiles of a field with a chosen geometry halo, and what they cost to render.

A tile *measures* its block of the measurement area (:meth:`lightfit.plant.Field.tiles`) and
*renders* a scene of its block plus a halo of surrounding plants. Two kinds of halo:

``halo_rows=None`` (default, exact)
    Every tile's scene is the whole field (measurement area + the field's buffer rows). The
    sample streams of the irradiance estimator are keyed by (render seed, segment id, sample
    index) and the scene around each segment is the same as in a single-process run, so each
    per-segment value is **bitwise identical** whatever the tiling (tested). Tiling then splits
    the *rays* (measured segments × samples), not the triangles.

``halo_rows=H`` (the reference paper's approach)
    A tile's scene is its block plus the plants within H rows/columns of it, clipped to the
    field (H = ``field.buffer_rows`` reproduces ``Field.tiles`` where the field has as many buffer
    plants along the rows as buffer rows, the default). Scenes are smaller (fewer
    triangles render faster, less memory per worker), but a segment near a tile boundary no
    longer sees the far geometry beyond H rows, so its value differs from the single-process
    run by a *bias* (light leaking in through the missing plants), not by Monte Carlo noise.
    The bias shrinks as H grows; its size is measured in ``benchmarks/bench_distributed.py``
    and stated in ``docs/distributed.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from lightfit.errors import InputError, check_integer
from lightfit.plant.field import ID_COLUMNS, ID_OFFSET, Field, Tile


def plant_rc(ids) -> tuple[np.ndarray, np.ndarray]:
    """Grid position (r, c) relative to the measurement area of plant ids (inverse of ``plant_id``)."""
    ids = np.asarray(ids, dtype=np.int64)
    return ids // ID_COLUMNS - ID_OFFSET, ids % ID_COLUMNS - ID_OFFSET


@dataclass(frozen=True, repr=False)  # Field's repr, which leaves out an unset plants_per_row
class HaloField(Field):
    """A :class:`~lightfit.plant.Field` whose tiles carry a geometry halo of ``halo_rows`` plants.

    Plants, ids, seeds and positions are those of :class:`Field` (a plant is the same whatever
    the tiling). Only :meth:`tiles` differs: the buffer of a tile is the whole rest of the field
    (``halo_rows=None``: exact) or the plants within ``halo_rows`` rows and columns of its block,
    clipped to the field's grid of M rows × M_along plants (``halo_rows=buffer_rows`` gives ``Field.tiles`` when
    ``buffer_along == buffer_rows``: ``Field.tiles`` pads the columns by ``buffer_along``). A periodic
    field (``boundary="periodic"``) takes only ``halo_rows=None``: its tiles render the whole cell.

    Attributes:
        halo_rows: plants of geometry around each tile (rows and columns), or ``None`` for
            the whole field.
    """

    halo_rows: int | None = None

    def __post_init__(self):
        super().__post_init__()
        if self.halo_rows is not None and (not isinstance(self.halo_rows, (int, np.integer)) or self.halo_rows < 0):
            raise InputError(
                f"halo_rows={self.halo_rows!r}",
                parameter="halo_rows",
                expected="an integer ≥ 0, or None for the whole field (exact)",
            )
        if self.periodic and self.halo_rows is not None:
            raise InputError(
                f"halo_rows={self.halo_rows!r} with boundary='periodic'",
                parameter="halo_rows",
                expected="None: light wraps through the whole periodic cell, so every tile renders all of it",
            )

    @classmethod
    def of(cls, fld: Field, halo_rows: int | None = None) -> HaloField:
        """The same field with a tile halo."""
        return cls(**_field_values(fld), halo_rows=halo_rows)

    def exact_halo_rows(self, n_tiles: int) -> int:
        """The fewest ``halo_rows`` with which each of ``n_tiles`` tiles holds every plant of the field
        (its renders are then those of one process): the farthest any plant lies from a tile, in rows
        or plants along them."""
        r_all, c_all = plant_rc(self.plants().index.to_numpy())
        far = 0
        for t in Field.tiles(self, n_tiles):
            r, c = plant_rc(t.measured)
            far = max(far, r.min() - r_all.min(), r_all.max() - r.max(), c.min() - c_all.min(), c_all.max() - c.max())
        return int(far)

    def base(self) -> Field:
        """The plain :class:`Field` (for single-process runs)."""
        return Field(**_field_values(self))

    def tiles(self, n_tiles: int = 1) -> list[Tile]:
        base = Field.tiles(self, n_tiles)  # validates n_tiles (InputError naming n_tiles)
        all_ids = self.plants().index.to_numpy()
        r_all, c_all = plant_rc(all_ids)
        out = []
        for t in base:
            if self.halo_rows is None:
                keep = np.ones(len(all_ids), bool)
            else:
                r, c = plant_rc(t.measured)
                h = self.halo_rows
                keep = (r_all >= r.min() - h) & (r_all <= r.max() + h) & (c_all >= c.min() - h) & (c_all <= c.max() + h)
            ring = np.setdiff1d(all_ids[keep], t.measured)
            out.append(Tile(index=t.index, measured=t.measured, buffer=np.sort(ring)))
        return out


def _field_values(fld: Field) -> dict:
    return {f.name: getattr(fld, f.name) for f in fields(Field)}


def check_tiles(fld: Field, n_tiles) -> list[Tile]:
    """``fld.tiles(n_tiles)`` with an error naming ``tiles`` when the partition is impossible."""
    n_tiles = check_integer(n_tiles, "tiles", 1)
    try:
        return fld.tiles(n_tiles)
    except InputError as err:
        raise InputError(f"tiles={n_tiles}: {err.problem}", parameter="tiles", expected=err.expected) from None


__all__ = ["HaloField", "check_tiles", "plant_rc"]
