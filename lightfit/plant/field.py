"""A field of wheat plants: grid, measurement area, boundary (buffer rows or periodic) and tiles.

Coordinates: x east, y north, z up, metres; the measurement area is centred on the origin.
Wheat rows run along ``row_direction_deg`` (compass azimuth, default 90° = east–west); within
a row plants are ``plant_spacing_m`` apart, rows are ``row_spacing_m`` apart.

The measurement area is N_rows rows of N_along plants: a square N × N (N = ⌈√n_plants⌉, the
next larger square, as the reference paper does) unless ``plants_per_row`` is given, then
⌈n_plants / plants_per_row⌉ rows of ``plants_per_row`` plants (500 plants as 20 × 25). Around it
stand B buffer rows across the rows and B_along buffer plants at either end of each row: the
whole grid is M = N_rows + 2B rows of M_along = N_along + 2B_along plants.
A plant is named by its position (r, c) relative to the measurement area's first plant
(buffer plants have r < 0 or ≥ N_rows, or c < 0 or ≥ N_along). That position fixes its id,
``plant_id = (r + 1000)·10⁴ + (c + 1000)`` (hence at most 1 000 buffer rows or plants along, and
N_along + B_along ≤ 9 000), its seed (:func:`plant_seed`) and its location, so
a plant is the same whichever tile builds it and however many buffer rows surround it. Tiles
partition the measurement area into W contiguous blocks, each carrying its own B buffer rows.

Two boundaries (``Field.boundary``):

- ``"finite"``: the measurement area plus its buffer rows, on bare soil (the reference paper's
  setup). Light leaks in through the edges: +53 % canopy absorbed PAR for the default 10 × 10
  plants with 2 buffer rows (+42 % with the reference paper's grey leaf; docs/light.md,
  "Field-edge bias").
- ``"periodic"``: the measurement area is one cell of an infinite field
  (:class:`~lightfit.plant.periodic.PeriodicCell`: N_along plants × plant spacing along the rows
  by N_rows rows × row spacing across them, so both spacings continue across the seam), and the light
  estimator wraps rays through it (docs/light.md, "Periodic boundary"). No buffer plants are
  grown; a tile's geometry is the whole cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from lightfit.defaults import (
    DEFAULT_PLANT_SPACING_M,
    DEFAULT_ROW_DIRECTION_DEG,
    DEFAULT_ROW_SPACING_M,
    HEADINGS,
    MAX_SPACING_M,
    SHEATHS,
)
from lightfit.errors import InputError, check_integer, check_real
from lightfit.plant.cache import load_or_grow
from lightfit.plant.growth import GrowthConfig, is_shoot, plant_seed
from lightfit.plant.mesh import Mesh, MeshResolution, shoot_mesh
from lightfit.plant.periodic import PeriodicCell, row_axes
from lightfit.plant.sheaths import check_sheaths, lay_sheaths

#: The reference paper found two rows of buffer plants around the measurement area sufficient.
DEFAULT_BUFFER_ROWS = 2
#: Field boundaries: buffer rows on bare soil, or one cell of an infinite periodic field.
BOUNDARIES = ("finite", "periodic")


#: Offset making relative plant coordinates non-negative in ids and seeds.
ID_OFFSET = 1000
#: Columns a plant id holds: c + ID_OFFSET < ID_COLUMNS (:func:`plant_id`).
ID_COLUMNS = 10_000


def _square_side(n_plants: int) -> int:
    """N = ⌈√n_plants⌉: the side of the square measurement area that holds ``n_plants``."""
    return math.isqrt(n_plants - 1) + 1


def plant_id(r: ArrayLike, c: ArrayLike) -> np.ndarray:
    """Stable plant id of the plant at (r, c) relative to the measurement area."""
    return (np.asarray(r) + ID_OFFSET) * ID_COLUMNS + (np.asarray(c) + ID_OFFSET)


def check_headings(headings) -> str:
    """``headings`` if it is one of :data:`HEADINGS`, else :class:`InputError` naming it."""
    if headings not in HEADINGS:
        raise InputError(f"headings={headings!r}", parameter="headings", expected=" or ".join(HEADINGS))
    return headings


def plant_heading_deg(seed: int) -> float:
    """A plant's heading, degrees in [0, 360): uniform, from the plant's own seed (so a plant faces
    the same way whichever tile builds it), on a stream apart from CPlantBox's use of the seed."""
    return float(np.random.default_rng([int(seed), 0x4EAD]).uniform(0.0, 360.0))


def turned(seg: pd.DataFrame, heading_deg: float) -> pd.DataFrame:
    """A copy of a plant's segment table (base at the origin) turned by ``heading_deg`` about the
    vertical through its base (counter-clockwise seen from above): end points and branching
    directions; z, lengths, radii and areas are unchanged."""
    seg = seg.copy()
    if heading_deg == 0.0:
        return seg
    c, s = math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))
    for x, y in (("x0", "y0"), ("x1", "y1"), ("bx", "by")):
        if x in seg:
            seg[x], seg[y] = c * seg[x] - s * seg[y], s * seg[x] + c * seg[y]
    return seg


@dataclass(frozen=True)
class Field:
    """Layout of a field.

    Attributes:
        n_plants: plants in the measurement area; rounded up to the next square N² (or, with
            ``plants_per_row``, to whole rows).
        row_spacing_m: distance between wheat rows, m (at most :data:`lightfit.defaults.MAX_SPACING_M`, 2 m).
        plant_spacing_m: distance between plants within a row, m (at most 2 m).
        buffer_rows: rows of unmeasured neighbour plants around the measurement area (and
            around each tile); default :data:`DEFAULT_BUFFER_ROWS` for a finite field, 0 (the
            only allowed value) for a periodic one.
        row_direction_deg: compass azimuth of the rows, degrees (90 = rows run east–west).
        seed: global seed; each plant's seed derives from it and the plant's grid position.
        growth: how plants are grown (parameter file, dates).
        buffer_along: buffer plants along each row at either end (default: ``buffer_rows``).
            Rows count plants, and plants stand much closer within a row (3 cm) than rows do
            (12.5 cm): two buffer rows are 25 cm across the rows but 6 cm along them, and light
            leaking in along the rows biases a small measurement area: +74 % canopy absorbed PAR
            on 4 × 4 plants of this wheat with 2 buffer rows and 2 along (+81 % with the rod
            sheaths; docs/light.md, "Field-edge bias").
            ``buffer_along ≈ buffer_rows · row_spacing / plant_spacing`` makes the buffer the
            same distance both ways. Periodic fields: ``None`` or 0.
        boundary: ``"periodic"`` (default: the measurement area is one cell of an infinite
            field, :attr:`cell`; no buffers, no edge bias) or ``"finite"`` (buffer rows on bare
            soil, the reference paper's setup, whose edges let in +50 to +100 % canopy light on
            small fields: docs/light.md, "Field-edge bias").
        sheaths: where each leaf's sheath (its basal zone) goes: ``"wrapped"`` (default) around the
            stem up to the collar, the blade starting there, or ``"rods"``, CPlantBox's thin rods
            at the leaf's insertion angle (the reference paper's geometry;
            :mod:`lightfit.plant.sheaths`, docs/plant.md "Leaf sheaths").
        headings: which way each plant faces: ``"random"`` (default) turns each plant about its base
            by its own angle (:meth:`plants`' ``heading_deg``, drawn from its seed: uniform in 0–360°),
            as plants in a field stand; ``"aligned"`` keeps CPlantBox's orientation, the same for every
            plant (its first leaf at the same azimuth; the reference paper's field): the canopy then has
            a preferred leaf azimuth, and a morning sun meets other leaf angles than an afternoon sun
            at the same elevation (docs/plant.md "Plant headings").
        plants_per_row: plants along each row of the measurement area; the area is then
            ⌈n_plants / plants_per_row⌉ rows of them (``n_plants=500, plants_per_row=25``: 20 rows × 25,
            exactly 500). ``None`` (default): a square N × N. Plants stand ≈ 4× closer within a row
            than rows do, so a square area is ≈ 4× longer across the rows than along them; about
            4× as many plants per row as rows makes it as long as wide in metres. That cuts a
            finite field's edge light (2 buffer rows: +52 % on 10 × 10, +30 % on 5 × 20) and leaves a
            periodic cell's canopy total as it is (docs/light.md, "Five draws of plants"). A square
            given as rows is the square (``plants_per_row`` becomes ``None``).
    """

    n_plants: int = 25
    row_spacing_m: float = DEFAULT_ROW_SPACING_M
    plant_spacing_m: float = DEFAULT_PLANT_SPACING_M
    buffer_rows: int | None = None
    row_direction_deg: float = DEFAULT_ROW_DIRECTION_DEG
    seed: int = 0
    growth: GrowthConfig = field(default_factory=GrowthConfig)
    buffer_along: int | None = None
    boundary: str = "periodic"
    sheaths: str = SHEATHS[0]
    headings: str = HEADINGS[0]
    plants_per_row: int | None = None

    def __post_init__(self):
        check_sheaths(self.sheaths)
        check_headings(self.headings)
        if not isinstance(self.growth, GrowthConfig):  # an AttributeError in build() or attrs()
            raise InputError(
                f"growth={self.growth!r}",
                parameter="growth",
                expected="a GrowthConfig (GrowthConfig(parameter_file=..., target_date=...))",
            )
        if self.boundary not in BOUNDARIES:
            raise InputError(f"boundary={self.boundary!r}", parameter="boundary", expected=" or ".join(BOUNDARIES))
        if self.boundary == "periodic":
            # Buffer plants would double the field inside the cell: refuse rather than ignore.
            for name in ("buffer_rows", "buffer_along"):
                if getattr(self, name) not in (None, 0):
                    raise InputError(
                        f"{name}={getattr(self, name)!r} with boundary='periodic'",
                        parameter=name,
                        expected=(
                            "0 or None: a periodic field (the default) has no buffer plants, its neighbours"
                            " are its own copies; boundary='finite' for buffer rows on bare soil"
                        ),
                    )
        if self.buffer_rows is None:  # frozen dataclass: set the boundary's default once
            object.__setattr__(self, "buffer_rows", DEFAULT_BUFFER_ROWS if self.boundary == "finite" else 0)
        if self.buffer_along is not None:
            # numpy's integers kept as Python's, as the spacings below: the repr keys caches and resumes
            object.__setattr__(
                self, "buffer_along", check_integer(self.buffer_along, "buffer_along", 0, why="or None for buffer_rows")
            )
        object.__setattr__(self, "n_plants", check_integer(self.n_plants, "n_plants", 1))
        if self.plants_per_row is not None:
            ppr = check_integer(
                self.plants_per_row,
                "plants_per_row",
                1,
                high=self.n_plants + 1,
                why=f"at most n_plants={self.n_plants}: one row holds them all; or None for a square area",
            )
            object.__setattr__(self, "plants_per_row", ppr)  # numpy's integers as Python's
            # A square given as rows is the square, under one name: the repr is a cache and resume key.
            if self.n_rows == self.n_along == _square_side(self.n_plants):
                object.__setattr__(self, "plants_per_row", None)
        for name in ("row_spacing_m", "plant_spacing_m"):
            v = check_real(
                getattr(self, name),
                name,
                0,
                MAX_SPACING_M,
                open_lo=True,
                expected=f"a positive distance in metres, at most {MAX_SPACING_M:g} m "
                "(centimetres given as metres read 100× too far apart: 12.5 for 0.125 m)",
            )
            object.__setattr__(self, name, v)  # np.float32(0.125) hashed otherwise than 0.125
        # NaN built a mesh of NaN, inf a math domain error; 400 was kept as 400 (the field of 40°
        # under another name and cache key)
        d = check_real(
            self.row_direction_deg,
            "row_direction_deg",
            0,
            360,
            open_hi=True,
            expected="a compass azimuth in degrees, 0 ≤ azimuth < 360 (rows at 270 run as at 90)",
        )
        object.__setattr__(self, "row_direction_deg", d)  # a float, as the spacings above
        b = check_integer(self.buffer_rows, "buffer_rows", 0, high=ID_OFFSET + 1, why="plant ids hold 1 000 rows")
        object.__setattr__(self, "buffer_rows", b)
        object.__setattr__(self, "seed", check_integer(self.seed, "seed", 0))
        if self.b_along > ID_OFFSET or self.n_along + self.b_along > ID_COLUMNS - ID_OFFSET:
            raise InputError(
                f"{self.n_along} plants per row and {self.b_along} buffer plants along them",
                parameter="plants_per_row" if self.plants_per_row is not None else "n_plants",
                expected=f"at most {ID_OFFSET} buffer plants along and {ID_COLUMNS - ID_OFFSET} plants per row with"
                " them (a plant id's columns)",
            )

    def __repr__(self) -> str:
        # ``plants_per_row`` only where set: the repr keys caches and resumes (Scenario.digest, the
        # emulator, field-run's tasks), and a square's must stay what it was before rows existed.
        shown = (f for f in fields(self) if f.repr and (f.name != "plants_per_row" or self.plants_per_row is not None))
        return f"{type(self).__qualname__}(" + ", ".join(f"{f.name}={getattr(self, f.name)!r}" for f in shown) + ")"

    @property
    def periodic(self) -> bool:
        """True for a periodic field."""
        return self.boundary == "periodic"

    def attrs(self) -> dict:
        """The field as netCDF attributes of a results file, what :meth:`from_attrs` rebuilds it from;
        ``growth_fingerprint`` (:meth:`~lightfit.plant.growth.GrowthConfig.fingerprint`: the plant file's
        contents, dates and CPlantBox version) tells whether a rebuild grows the same plants, and
        ``layout_fingerprint`` (:meth:`layout_fingerprint`) whether it places them alike."""
        return {
            "growth_fingerprint": self.growth.fingerprint(),
            "layout_fingerprint": self.layout_fingerprint(),
            "n_plants": self.n_plants,
            "boundary": self.boundary,
            "buffer_rows": self.buffer_rows,
            "buffer_along": self.b_along,
            "sheaths": self.sheaths,
            "headings": self.headings,
            "seed": self.seed,
            "parameter_file": self.growth.parameter_file,
            "season_start": self.growth.season_start,
            "target_date": self.growth.target_date,
            "row_spacing_m": self.row_spacing_m,
            "plant_spacing_m": self.plant_spacing_m,
            "row_direction_deg": self.row_direction_deg,
        } | ({} if self.plants_per_row is None else {"plants_per_row": self.plants_per_row})

    def layout_fingerprint(self) -> str:
        """SHA-256 (first 16 hex digits) of every plant's id, position and heading (:meth:`plants`, to
        a nanometre and a nanodegree): two fields with the same attributes but plants placed or turned
        otherwise (another ``seed``: other headings) differ here, where their segment areas agree."""
        import hashlib

        p = self.plants()
        table = np.column_stack([p["plant_id"], p["x_m"], p["y_m"], p["heading_deg"]]).round(9)
        return hashlib.sha256(np.ascontiguousarray(table, dtype=np.float64).tobytes()).hexdigest()[:16]

    @staticmethod
    def from_attrs(attrs, file=None) -> Field:
        """The field a results file describes (:meth:`attrs`); ``file`` names it in errors. Files
        written before a key existed ran with what it was then: a finite field (``boundary``),
        CPlantBox's rod sheaths (``sheaths``), aligned plants (``headings``), the layout and growth
        defaults, a square measurement area (``plants_per_row``)."""
        a, where = attrs, file or "results"

        def number(key: str, kind=float):
            if key not in a:
                raise InputError(f"no attribute {key}", file=where, column=key, expected="the field's attributes")
            try:
                return kind(a[key])
            except (TypeError, ValueError):
                what = "an integer" if kind is int else "a number"
                raise InputError(f"{key}={a[key]!r}", file=where, column=key, expected=what) from None

        growth = {k: str(a[k]) for k in ("parameter_file", "season_start", "target_date") if k in a}
        kw = {k: number(k) for k in ("row_spacing_m", "plant_spacing_m", "row_direction_deg") if k in a}
        boundary = str(a.get("boundary", "finite"))
        if boundary not in BOUNDARIES:
            raise InputError(f"boundary={boundary!r}", file=where, expected=f"attr boundary {' or '.join(BOUNDARIES)}")
        periodic = boundary == "periodic"
        try:  # the attributes' values checked as the field checks them, errors naming the file
            return Field(
                n_plants=number("n_plants", int),
                buffer_rows=None if periodic else number("buffer_rows", int),
                seed=number("seed", int),
                buffer_along=number("buffer_along", int) if "buffer_along" in a and not periodic else None,
                growth=GrowthConfig(**growth),
                boundary=boundary,
                sheaths=check_sheaths(str(a.get("sheaths", "rods"))),
                headings=check_headings(str(a.get("headings", "aligned"))),
                plants_per_row=number("plants_per_row", int) if "plants_per_row" in a else None,
                **kw,
            )
        except InputError as e:
            raise (e if e.file is not None else e.in_file(where)) from None

    @property
    def cell(self) -> PeriodicCell | None:
        """The periodic cell (bounds in metres: ``cell.bounds_m`` in the row frame,
        ``cell.corners_xy`` in x, y), centred on the origin; ``None`` for a finite field.

        N_along plants × plant spacing along the rows by N_rows rows × row spacing across them: every
        plant of the measurement area sits in the middle of its own spacing × spacing patch, so
        the spacings continue across the seam.
        """
        return self.measured_rectangle if self.periodic else None

    @property
    def measured_rectangle(self) -> PeriodicCell:
        """The measurement area as a rectangle in the row frame, centred on the origin, for either
        boundary (:attr:`cell` for a periodic field): N_along plants × plant spacing along the rows
        by N_rows rows × row spacing across them, each plant in the middle of its own patch."""
        return PeriodicCell(
            along_m=self.n_along * float(self.plant_spacing_m),
            across_m=self.n_rows * float(self.row_spacing_m),
            row_direction_deg=float(self.row_direction_deg),
        )

    @property
    def n_along(self) -> int:
        """Plants along each row of the measurement area: ``plants_per_row``, or the square's side
        N = ⌈√n_plants⌉."""
        return _square_side(self.n_plants) if self.plants_per_row is None else int(self.plants_per_row)

    @property
    def n_rows(self) -> int:
        """Rows of the measurement area: ⌈n_plants / plants per row⌉ (the square's side N without
        ``plants_per_row``)."""
        return self.n_along if self.plants_per_row is None else -(-self.n_plants // self.n_along)

    @property
    def n_measured(self) -> int:
        """Plants of the measurement area the field builds, rows × plants per row: ``n_plants``
        rounded up to a square N² (or to whole rows with ``plants_per_row``)."""
        return self.n_rows * self.n_along

    @property
    def area_label(self) -> str:
        """The measurement area in words: ``"10 rows × 10 plants"``."""
        rows, along = self.n_rows, self.n_along
        return f"{rows} row{'' if rows == 1 else 's'} × {along} plant{'' if along == 1 else 's'}"

    @property
    def b_along(self) -> int:
        """Buffer plants along each row at either end."""
        return self.buffer_rows if self.buffer_along is None else int(self.buffer_along)

    @property
    def m(self) -> int:
        """Rows of the whole grid including buffers."""
        return self.n_rows + 2 * self.buffer_rows

    @property
    def m_along(self) -> int:
        """Plants per row of the whole grid including buffers."""
        return self.n_along + 2 * self.b_along

    @property
    def area_per_plant_m2(self) -> float:
        """Ground area of one plant, m²: plant spacing × row spacing."""
        return self.plant_spacing_m * self.row_spacing_m

    @property
    def ground_area_m2(self) -> float:
        """Ground area of the measurement area, m²: its plants × plant spacing × row spacing."""
        return self.n_measured * self.area_per_plant_m2

    def measured_area_m2(self, tile: Tile | None = None) -> float:
        """Ground area of the plants a tile measures, m² (``None``: the whole measurement area)."""
        return self.ground_area_m2 if tile is None else len(tile.measured) * self.area_per_plant_m2

    def plants(self) -> pd.DataFrame:
        """One row per plant of the whole grid: ids, grid position, seed, position (m), heading
        (degrees, counter-clockwise seen from above; 0 for ``headings="aligned"``), measured flag.

        ``row``/``col`` index the grid (rows 0 … M−1, plants along a row 0 … M_along−1);
        ``r``/``c`` are relative to the measurement area (0 … N_rows − 1 and 0 … N_along − 1 inside it).
        """
        m, b, ma, ba = self.m, self.buffer_rows, self.m_along, self.b_along
        row, col = np.divmod(np.arange(m * ma), ma)
        r, c = row - b, col - ba
        along = (col - (ma - 1) / 2) * self.plant_spacing_m
        across = (row - (m - 1) / 2) * self.row_spacing_m
        d, p = row_axes(self.row_direction_deg)
        x = along * d[0] + across * p[0]
        y = along * d[1] + across * p[1]
        measured = (r >= 0) & (r < self.n_rows) & (c >= 0) & (c < self.n_along)
        seeds = [plant_seed(self.seed, int(i) + ID_OFFSET, int(j) + ID_OFFSET) for i, j in zip(r, c)]
        return pd.DataFrame(
            {
                "plant_id": plant_id(r, c),
                "row": row,
                "col": col,
                "r": r,
                "c": c,
                "seed": seeds,
                "x_m": x,
                "y_m": y,
                "heading_deg": [plant_heading_deg(s) if self.headings == "random" else 0.0 for s in seeds],
                "measured": measured,
            }
        ).set_index("plant_id", drop=False)

    def tiles(self, n_tiles: int = 1) -> list[Tile]:
        """Partition the measurement area into ``n_tiles`` blocks, each with its buffer ring.

        The block grid is a blocks across the rows by b along them, a × b = n_tiles: the most nearly
        square factorisation that fits the area, of two as square the one with the smaller largest
        block, then the larger count along the rows unless the area has more rows than plants per
        row (6 tiles of a square: 2 × 3; of 20 rows × 3 plants: 2 × 3, blocks of 10); rows and columns are split
        as evenly as possible. In a periodic field a tile's buffer is the rest of the cell: light
        wraps through the whole cell, so every tile needs all of it.
        """
        if not isinstance(n_tiles, (int, np.integer)) or n_tiles < 1:
            raise InputError(f"n_tiles={n_tiles!r}", parameter="n_tiles", expected="an integer ≥ 1")
        more_rows = self.n_rows > self.n_along

        def order(ab):  # squarest first, then the more even blocks, then more blocks on the longer side
            a, b = ab
            largest = -(-self.n_rows // a) * -(-self.n_along // b)
            return abs(a - b), largest, (a > b) != more_rows

        pairs = sorted(((d, n_tiles // d) for d in range(1, n_tiles + 1) if n_tiles % d == 0), key=order)
        fit = [(a, b) for a, b in pairs if a <= self.n_rows and b <= self.n_along]
        if not fit:
            raise InputError(
                f"{n_tiles} tiles do not fit a {self.n_rows}×{self.n_along} measurement area",
                parameter="n_tiles",
                expected=f"a × b tiles with a ≤ {self.n_rows} across the rows and b ≤ {self.n_along} along them",
            )
        a, bcount = fit[0]
        B, m, Ba, ma = self.buffer_rows, self.m, self.b_along, self.m_along
        rows = np.array_split(np.arange(B, B + self.n_rows), a)
        cols = np.array_split(np.arange(Ba, Ba + self.n_along), bcount)
        out = []
        for rr in rows:
            for cc in cols:
                r0, r1, c0, c1 = rr[0], rr[-1], cc[0], cc[-1]
                R, C = np.meshgrid(
                    np.arange(max(0, r0 - B), min(m, r1 + B + 1)),
                    np.arange(max(0, c0 - Ba), min(ma, c1 + Ba + 1)),
                    indexing="ij",
                )
                inside = (R >= r0) & (R <= r1) & (C >= c0) & (C <= c1)
                ids = plant_id(R - B, C - Ba)
                measured = np.sort(ids[inside])
                if self.periodic:
                    everyone = plant_id(*np.divmod(np.arange(self.n_measured), self.n_along))
                    buffer = np.sort(np.setdiff1d(everyone, measured))
                else:
                    buffer = np.sort(ids[~inside])
                out.append(Tile(index=len(out), measured=measured, buffer=buffer))
        return out


@dataclass(frozen=True)
class Tile:
    """One block of the partition: the plants it measures and the buffer plants around them."""

    index: int
    measured: np.ndarray
    buffer: np.ndarray

    @property
    def plant_ids(self) -> np.ndarray:
        return np.sort(np.concatenate([self.measured, self.buffer]))


@dataclass
class FieldGeometry:
    """Built geometry of (part of) a field.

    Attributes:
        segments: shoot segment table of all plants built, placed in field coordinates, with
            ``measured`` (bool: the segment's plant is in the measurement area or tile).
        mesh: shoot mesh; ``mesh.face_segment`` refers to ``segments.segment_id``.
        plants: the plant rows built (see :meth:`Field.plants`).
        cache_hits: plants loaded from the cache rather than simulated.
        cell: the periodic cell the mesh fills (``Field.cell``), ``None`` for a finite field;
            pass it to :class:`lightfit.light.scene.FieldScene`.
    """

    segments: pd.DataFrame
    mesh: Mesh
    plants: pd.DataFrame
    cache_hits: int = 0
    cell: PeriodicCell | None = None


def build(
    fld: Field,
    *,
    tile: Tile | None = None,
    resolution: MeshResolution = MeshResolution(),
    cache_dir: str | Path | None = None,
    progress: bool = False,
) -> FieldGeometry:
    """Grow (or load from cache), place, lay the sheaths of (``fld.sheaths``) and mesh the plants
    of a field or of one tile.

    Without ``tile``: the whole grid, measured = the measurement area. With a tile: its
    plants and its buffer ring, measured = the tile's own plants (periodic: the whole cell is
    built, measured = the tile's plants).
    """
    if not isinstance(fld, Field):  # an AttributeError further in
        raise InputError(f"fld of type {type(fld).__name__}", parameter="fld", expected="a Field (Field(n_plants=16))")
    table = fld.plants()
    if tile is None:
        ids, measured_ids = table.index.to_numpy(), table.index[table["measured"]].to_numpy()
    else:
        ids, measured_ids = tile.plant_ids, tile.measured
        if not np.isin(ids, table.index.to_numpy()).all():  # a KeyError listing every plant id
            raise InputError(
                f"tile {tile.index} holds plants that {fld.area_label} ({fld.boundary}) does not",
                parameter="tile",
                expected="a tile of this field: fld.tiles(n)[k]",
            )
    chosen = table.loc[ids]
    parts, hits = [], 0
    it = chosen.itertuples()
    if progress:
        from rich.progress import track

        it = track(list(it), description=f"growing {len(chosen)} plants", transient=True)
    measured_set = set(int(i) for i in measured_ids)
    for p in it:
        seg, hit = load_or_grow(fld.growth, p.seed, int(p.plant_id), directory=cache_dir)
        hits += hit
        seg = turned(seg, p.heading_deg)
        for c0, c1, off in (("x0", "x1", p.x_m), ("y0", "y1", p.y_m)):
            seg[c0] += off
            seg[c1] += off
        seg["measured"] = int(p.plant_id) in measured_set
        parts.append(seg)
    segments = pd.concat(parts, ignore_index=True)
    segments = segments[is_shoot(segments)].reset_index(drop=True)
    if not (segments["blade_area_m2"] > 0).any():  # every leaf a sheath: nothing would photosynthesise
        raise InputError(
            f"the plants grown to {fld.growth.target_date} have no leaf blade (every leaf segment is sheath)",
            file=fld.growth.path,
            parameter="parameter_file",
            expected="a wheat parameter file whose leaves have blades (lmaxb, Width_blade), or a later target date",
        )
    segments = lay_sheaths(segments, fld.sheaths)
    return FieldGeometry(segments, shoot_mesh(segments, resolution), chosen, hits, fld.cell)
