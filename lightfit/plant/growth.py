"""Grow one wheat plant with CPlantBox and export its segment table (G1).

CPlantBox (Schnepf et al. 2018, Zhou et al. 2020; Giraud et al. 2023 for the wheat shoot) works
in cm and days. The segment table converts to metres; its columns (docs/design.md §3):

========================  ==========================================================
``plant_id``              the plant's field id, (r + 1000)·10⁴ + (c + 1000) from its row and
                          column (:func:`lightfit.plant.field.plant_id`); 0 for one plant
``segment_index``         CPlantBox segment index within the plant (= end node − 1)
``segment_id``            stable field-wide id: ``plant_id * SEGMENT_ID_STRIDE + segment_index``
``organ_type``            ``"root"``, ``"stem"`` or ``"leaf"``
``organ_id``              CPlantBox organ id (unique within the plant)
``x0 y0 z0 x1 y1 z1``     segment end points, m (plant base at the origin before placement)
``length_m``              segment length, m
``radius_m``              CPlantBox radius, m (stems, roots, leaf sheaths)
``blade_width_m``         leaf blade width, m (one-sided blade area / length; 0 off-blade)
``blade_area_m2``         one-sided leaf blade area, m² (CPlantBox ``leafBladeSurface``)
``creation_time_d``       days after the season start at which the segment's end formed
``bx by bz``              branching direction: unit axis of the parent organ where the
                          organ branches off (used to orient leaf blades)
========================  ==========================================================
"""

from __future__ import annotations

import datetime as dt
import hashlib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from lightfit.defaults import DEFAULT_DATE, DEFAULT_PARAMETER_FILE, SEASON_START_MONTH_DAY
from lightfit.errors import InputError, parse_date

#: Organ type numbers of CPlantBox (``pb.OrganTypes``).
ORGAN_NAMES = {2: "root", 3: "stem", 4: "leaf"}
#: Organs that enter the light model.
SHOOT_ORGANS = ("stem", "leaf")
#: The categories of a segment table's ``organ_type`` (:data:`ORGAN_NAMES`' and what CPlantBox may add).
ORGAN_CATEGORIES = ["root", "stem", "leaf", "other"]


def default_season_start(dates) -> str | None:
    """The season start growth takes when none is given for ``dates`` (YYYY-MM-DD each):
    :data:`SEASON_START_MONTH_DAY` of their year, or ``None`` where they span several years (each
    then has its own)."""
    years = {parse_date(d, "date").year for d in dates}
    return dt.date(years.pop(), *SEASON_START_MONTH_DAY).isoformat() if len(years) == 1 else None


#: Segment ids are ``plant_id * SEGMENT_ID_STRIDE + segment_index``: stable across tiles.
SEGMENT_ID_STRIDE = 1_000_000
CM = 0.01
#: Longest growth the wheat parameter sets describe, days after ``season_start``. CPlantBox's wheat
#: has no senescence or ripening: organs reach their maximum length (``lmax``) and stay green. With
#: the default file the blade area is final by ≈ 43 days (153.0 cm² per plant from 17 April on;
#: 20 April, 23 June and 30 September alike) while the stem goes on lengthening (18 cm on 20 April,
#: 32 cm on 23 June): docs/plant.md, "Limits of the default canopy". Winter wheat in the Lower Rhine
#: basin is harvested in mid to late July (≈ 140 days after 5 March); 150 days ends the growth
#: model's range with a little slack.
MAX_GROWTH_DAYS = 150


def organ_class(segments: pd.DataFrame) -> np.ndarray:
    """Each segment's organ class: ``"blade"`` (a leaf segment with blade width: a two-sided ribbon,
    the only segments with photosynthesis), ``"sheath"`` (a leaf segment without: CPlantBox's basal
    zone, a prism of the leaf radius; docs/plant.md), else its ``organ_type`` (``"stem"``,
    ``"root"``, ``"other"``)."""
    organ = segments["organ_type"].to_numpy(dtype=str)
    blade = (organ == "leaf") & (segments["blade_width_m"].to_numpy() > 0)
    return np.where(blade, "blade", np.where(organ == "leaf", "sheath", organ))


def one_sided_area_m2(segments: pd.DataFrame) -> np.ndarray:
    """Each segment's one-sided area, m²: the blade area (one side) for blades, the lateral surface
    2πrL for stems, sheaths and roots."""
    blade = organ_class(segments) == "blade"
    lateral = 2 * np.pi * segments["radius_m"].to_numpy() * segments["length_m"].to_numpy()
    return np.where(blade, segments["blade_area_m2"].to_numpy(), lateral)


def centre_height_m(segments: pd.DataFrame) -> np.ndarray:
    """Each segment's centre height above the soil (z = 0), m: the mean of its end points' z."""
    return 0.5 * (segments["z0"].to_numpy() + segments["z1"].to_numpy())


def parameter_dir() -> Path:
    """CPlantBox's bundled plant structure parameter directory."""
    import plantbox

    return Path(plantbox.__file__).resolve().parent / "modelparameter" / "structural" / "plant"


def _bundled(name: str | os.PathLike) -> Path | None:
    """CPlantBox's bundled file of that bare name (no folder in it), if there is one."""
    if isinstance(name, str) and name and Path(name).name == name:
        p = parameter_dir() / name
        return p if p.is_file() else None
    return None


def parameter_file_setting(name: str | os.PathLike) -> str:
    """A parameter file as a run records it: a bundled file's bare name as given, another existing
    path made absolute (a relative one names another file, or none, from another folder: a results
    file read back there, a resumed run). Looked up as :func:`resolve_parameter_file` does."""
    p = Path(name)
    return str(name) if _bundled(name) is not None or not p.exists() else str(p.resolve())


def resolve_parameter_file(name: str | os.PathLike) -> Path:
    """A plant parameter XML: a bare file name in CPlantBox's bundled set is that file; anything else
    a path (an edited copy in the working folder under a bundled name is read as ``./NAME``: the
    default run, which names its file bare, never picks up a local copy unsaid).

    Raises :class:`InputError` listing the bundled wheat files when it does not exist or is not
    a CPlantBox ``<plant>`` XML.
    """
    p = _bundled(name) or Path(name)
    if not p.exists():
        p = parameter_dir() / str(name)
    if not p.exists():
        wheat = sorted(f.name for f in parameter_dir().glob("Triticum_aestivum_*.xml"))
        raise InputError(
            f"plant parameter file {str(name)!r} not found",
            parameter="parameter_file",
            expected=f"a path or one of CPlantBox's wheat files: {', '.join(wheat)}",
        )
    if not p.is_file():
        raise InputError(
            "a folder, not a file", file=p, parameter="parameter_file", expected="a plant parameter XML file"
        )
    import xml.etree.ElementTree as ET

    try:  # CPlantBox reads a broken file in part and fails later, far from the file (a review)
        root = ET.parse(p).getroot()
    except (ET.ParseError, UnicodeDecodeError) as err:
        raise InputError(
            f"not well-formed XML ({err})", file=p, expected="an XML file such as Triticum_aestivum_adapted_2023.xml"
        ) from None
    if root.tag != "plant" and root.find(".//plant") is None:
        raise InputError(
            "not a CPlantBox plant parameter file (no <plant> element)",
            file=p,
            expected="an XML file such as Triticum_aestivum_adapted_2023.xml",
        )
    _check_parameters(root, p)
    return p


#: ``<parameter>`` attributes that hold numbers (CPlantBox reads a word in them as 0, unsaid); a
#: successor's may hold a comma-separated list of them.
_NUMERIC_ATTRIBUTES = ("value", "dev", "phi", "x", "percentage", "numLat", "subType", "organType", "ruleId")
#: Parameters CPlantBox reads by their own structure, not by name lookup.
_STRUCTURAL = {"successor", "leafGeometry"}


def _check_parameters(root, path: Path) -> None:
    """Every ``<parameter>`` of an organ holds finite numbers and names a parameter CPlantBox knows
    for some organ: CPlantBox reads a word as a value and an unknown name without a word (a typo gave
    a traceback from deep in the growth, or a different plant; a review of bad input). A name of
    another organ's is let through, as CPlantBox's own example files hold some (a root's ``lnk`` on
    a stem), which it ignores."""
    import difflib

    import plantbox as pb

    classes = {
        "seed": pb.SeedRandomParameter,
        "root": pb.RootRandomParameter,
        "stem": pb.StemRandomParameter,
        "leaf": pb.LeafRandomParameter,
    }
    plant = pb.MappedPlant(0)
    organs = {tag: cls(plant) for tag, cls in classes.items()}
    for organ in root.iter():
        if organ.tag not in classes:
            continue
        where = f"<{organ.tag} subType={organ.get('subType', '?')}>"
        for par in organ.iter("parameter"):
            name = par.get("name", "")
            for attr in _NUMERIC_ATTRIBUTES:
                text = par.get(attr)
                try:
                    ok = text is None or all(math.isfinite(float(v)) for v in text.split(","))
                except ValueError:
                    ok = False
                if not ok:
                    raise InputError(
                        f"{where} parameter {name!r}: {attr}={text!r}",
                        file=path,
                        parameter="parameter_file",
                        expected=f"a finite number in {attr}=",
                    )
            if name not in _STRUCTURAL and all(math.isnan(o.getParameter(name)) for o in organs.values()):
                close = difflib.get_close_matches(name, _known_names(organs[organ.tag]), n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise InputError(
                    f"{where}: CPlantBox knows no parameter {name!r}{hint}",
                    file=path,
                    parameter="parameter_file",
                    expected=f"a {organ.tag} parameter of CPlantBox's (its bundled files show them)",
                )


def _known_names(organ_parameters) -> list[str]:
    """The parameter names CPlantBox lists for an organ (the first word of each line of its own
    description, which tabulates them), for a suggestion."""
    lines = str(organ_parameters).splitlines()
    return [w for line in lines if (w := (line.split() or [""])[0]) and w[0].isalpha()]


@dataclass(frozen=True)
class GrowthConfig:
    """How plants are grown.

    Attributes:
        parameter_file: CPlantBox plant XML (path or bundled name). Default
            ``Triticum_aestivum_adapted_2023.xml``: the winter wheat set adapted for the
            Selhausen experiments (Giraud et al. 2023), one main stem, no tillers.
        season_start: first day of simulated growth; default ``None``: 5 March of ``target_date``'s
            year (:data:`SEASON_START_MONTH_DAY`; the reference paper's 2016-03-05: the crop was
            sown 2015-10-26, growth over winter is not simulated). Resolved when the config is
            made: ``dataclasses.replace(config, target_date=...)`` keeps the resolved date (pass
            ``season_start=None`` with it to take the new year's).
        target_date: date the plants are grown to (the measurement day, 2016-04-20): after
            ``season_start`` and at most :data:`MAX_GROWTH_DAYS` days after it. Both dates may be
            given as text or ``datetime.date``; they are kept as ``YYYY-MM-DD`` text.
        include_roots: keep root segments in the table. Off by default: roots are ~98 % of a
            wheat plant's segments and never enter the light model.
    """

    parameter_file: str = DEFAULT_PARAMETER_FILE
    season_start: str | None = None
    target_date: str = DEFAULT_DATE
    include_roots: bool = False
    _path: Path = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if not isinstance(self.parameter_file, (str, os.PathLike)):  # Path(None): a TypeError
            raise InputError(
                f"parameter_file={self.parameter_file!r}",
                parameter="parameter_file",
                expected=f"a file name or path (default {DEFAULT_PARAMETER_FILE})",
            )
        # Kept as text: the repr keys caches and resumes, and attrs() go into netCDF results, which
        # hold no Path (a pathlib.Path failed the results file's write at the end of a run).
        object.__setattr__(self, "parameter_file", os.fspath(self.parameter_file))
        end = parse_date(self.target_date, "target_date")
        default = self.season_start is None
        if default:  # frozen: set once; recorded as a date, so that repr, attrs and keys name it
            object.__setattr__(self, "season_start", default_season_start([end.isoformat()]))
        start = parse_date(self.season_start, "season_start")
        # Recorded as YYYY-MM-DD text, whatever form they came in (a date, a datetime, 20160420): the
        # repr keys caches and resumes, and attrs() go into netCDF results, which hold no date objects.
        object.__setattr__(self, "season_start", start.isoformat())
        object.__setattr__(self, "target_date", end.isoformat())
        if end <= start:
            raise InputError(
                f"target_date {end} is not after season_start {start}"
                + (" (the default: 5 March of its year; growth over winter is not simulated)" if default else ""),
                parameter="target_date",
                expected="season_start < target_date" + (", a date after 5 March" if default else ""),
            )
        if (end - start).days > MAX_GROWTH_DAYS:
            raise InputError(
                f"target_date {end} is {(end - start).days} days after season_start {start}, beyond the "
                f"wheat growth model's range (no senescence or ripening; harvest is in July)",
                parameter="target_date",
                expected=f"a date at most {MAX_GROWTH_DAYS} days after season_start",
            )
        if not isinstance(self.include_roots, bool):  # "no" is a true value: the roots were kept
            raise InputError(
                f"include_roots={self.include_roots!r}", parameter="include_roots", expected="True or False"
            )
        object.__setattr__(self, "_path", resolve_parameter_file(self.parameter_file))

    @property
    def path(self) -> Path:
        return self._path

    @property
    def days(self) -> float:
        """Simulated growth duration, days."""
        return float((parse_date(self.target_date, "target_date") - parse_date(self.season_start, "season_start")).days)

    def fingerprint(self) -> str:
        """Hash of everything that determines a grown plant except its seed."""
        import importlib.metadata as md

        h = hashlib.sha256()
        h.update(self.path.read_bytes())
        # the dates as dates: "20160420" and "2016-04-20" grow the same plants
        start = parse_date(self.season_start, "season_start").isoformat()
        end = parse_date(self.target_date, "target_date").isoformat()
        key = f"{start}|{end}|roots={self.include_roots}|cplantbox {md.version('cplantbox')}"
        h.update(key.encode())
        return h.hexdigest()[:16]


def plant_seed(global_seed: int, row: int, col: int) -> int:
    """Seed of the plant at grid position (row, col), derived from the field's global seed.

    ``numpy.random.SeedSequence`` hashes (global_seed, row, col) into a well-mixed 31-bit
    integer, so any worker can rebuild any plant — its own or a neighbour in its buffer —
    without communication (the reference paper's scheme).
    """
    if min(global_seed, row, col) < 0:
        raise InputError(
            "seeds and grid positions must be non-negative",
            parameter="seed",
            expected=f"global_seed ≥ 0, row ≥ 0, col ≥ 0; got {global_seed}, {row}, {col}",
        )
    return int(np.random.SeedSequence([int(global_seed), int(row), int(col)]).generate_state(1)[0] >> 1)


def grow_plant(config: GrowthConfig, seed: int, plant_id: int = 0) -> pd.DataFrame:
    """Simulate one plant from ``season_start`` to ``target_date``; return its segment table.

    Deterministic: the same config and seed give the same table bit for bit.
    """
    import plantbox as pb

    plant = pb.MappedPlant(int(seed))
    try:  # CPlantBox's own errors name an organ type, not the file that lacks it
        plant.readParameters(str(config.path))
        plant.initialize(False)
        plant.simulate(config.days, False)
    except (ValueError, RuntimeError, IndexError) as err:  # IndexError: C++'s std::out_of_range
        raise InputError(
            f"CPlantBox cannot grow a plant from it ({err})",
            file=config.path,
            parameter="parameter_file",
            expected="a complete CPlantBox plant parameter file (seed, root, stem and leaf parameters)",
        ) from None
    table = segment_table(plant, plant_id, include_roots=config.include_roots)
    if not config.include_roots:
        table = table[table["organ_type"] != "root"].reset_index(drop=True)
    return table


def segment_table(plant: Any, plant_id: int = 0, include_roots: bool = True) -> pd.DataFrame:
    """Segment table (see module docstring) of a simulated CPlantBox ``MappedPlant``.

    With ``include_roots=False`` root organs are not visited (their ``organ_id`` stays −1),
    which is 5× faster for wheat.
    """
    # The mapped node list, the one ``plant.segments`` index (as the radii, organ types and node times
    # are mapped): ``getNodes()`` collects the organs' nodes and can miss one (CPlantBox's bundled
    # Zea_mays_4_Leitner_2014.xml, Pisum_sativum_b_TSEGAYE_1995.xml: one node short, an IndexError).
    nodes = np.array(plant.nodes, dtype=float) * CM
    segs = np.array([[s.x, s.y] for s in plant.segments], dtype=np.int64)
    if not np.array_equal(segs[:, 1], np.arange(1, len(segs) + 1)):
        raise RuntimeError("CPlantBox segment order changed: segment i no longer ends at node i + 1")
    n = len(segs)
    if n >= SEGMENT_ID_STRIDE:  # ids plant_id · stride + index would run into the next plant's
        raise InputError(
            f"a plant of {n} segments (roots counted: CPlantBox indexes them with the shoot)",
            parameter="parameter_file",
            expected=f"plants of fewer than {SEGMENT_ID_STRIDE:,} segments (an earlier date, a coarser resolution)",
        )
    organ_id = np.full(n, -1, dtype=np.int64)
    branch = np.tile([0.0, 0.0, 1.0], (n, 1))
    organs = {o.getId(): o for t in ((2, 3, 4) if include_roots else (3, 4)) for o in plant.getOrgans(t)}
    d = nodes[segs[:, 1]] - nodes[segs[:, 0]]
    length = np.linalg.norm(d, axis=1)
    unit = d / np.where(length > 0, length, 1.0)[:, None]
    for oid, o in organs.items():
        ids = np.asarray(o.getNodeIds(), dtype=np.int64)
        if len(ids) < 2:
            continue
        seg_idx = ids[1:] - 1
        organ_id[seg_idx] = oid
        # Branching direction: the parent's axis at the branch node (the segment ending there),
        # else the parent's first segment, else vertical.
        parent = o.getParent() if o.organType() != 1 else None
        b = np.array([0.0, 0.0, 1.0])
        if parent is not None and parent.organType() >= 2 and ids[0] > 0:
            b = unit[ids[0] - 1]
        elif parent is not None and parent.organType() >= 2:
            pids = np.asarray(parent.getNodeIds(), dtype=np.int64)
            if len(pids) > 1:
                b = unit[pids[1] - 1]
        branch[seg_idx] = b
    ot = np.asarray(plant.organTypes, dtype=np.int64)
    area = np.asarray(plant.leafBladeSurface, dtype=float) * CM * CM
    # CPlantBox leaves ~1e-19 m² of round-off where the blade begins; that is sheath, not blade.
    area = np.where(area < 1e-12, 0.0, area)
    radius = np.asarray(plant.radii, dtype=float) * CM
    ct = np.asarray(plant.nodeCTs, dtype=float)[segs[:, 1]]
    width = np.where((ot == 4) & (area > 0) & (length > 0), area / np.where(length > 0, length, 1.0), 0.0)
    return pd.DataFrame(
        {
            "plant_id": np.full(n, plant_id, dtype=np.int64),
            "segment_index": np.arange(n, dtype=np.int64),
            "segment_id": plant_id * SEGMENT_ID_STRIDE + np.arange(n, dtype=np.int64),
            "organ_type": pd.Categorical([ORGAN_NAMES.get(int(t), "other") for t in ot], categories=ORGAN_CATEGORIES),
            "organ_id": organ_id,
            "x0": nodes[segs[:, 0], 0],
            "y0": nodes[segs[:, 0], 1],
            "z0": nodes[segs[:, 0], 2],
            "x1": nodes[segs[:, 1], 0],
            "y1": nodes[segs[:, 1], 1],
            "z1": nodes[segs[:, 1], 2],
            "length_m": length,
            "radius_m": radius,
            "blade_width_m": width,
            "blade_area_m2": np.where(ot == 4, area, 0.0),
            "creation_time_d": ct,
            "bx": branch[:, 0],
            "by": branch[:, 1],
            "bz": branch[:, 2],
        }
    )


def is_shoot(segments: pd.DataFrame) -> np.ndarray:
    """Which segments enter the light model: stems and leaves (:data:`SHOOT_ORGANS`), not roots."""
    return segments["organ_type"].isin(SHOOT_ORGANS).to_numpy()
