"""Mitsuba scene of a field: plant mesh with the leaf BSDF, a soil plane, the sun and the sky.

Units are relative: the sun has unit irradiance on a plane normal to its beam (DNI = 1), the
sky unit irradiance on an unoccluded horizontal plane (DHI = 1), so a time step's weather only
rescales the sun part and the sky part (docs/design.md §3).

Geometry conventions: x east, y north, z up, metres; the soil is the plane z = 0.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from lightfit.defaults import SKY_MODELS, SOIL_ALBEDO
from lightfit.errors import InputError, check_fraction, is_real
from lightfit.light.backend import mitsuba
from lightfit.light.bsdf import LEAF_PARAMETERS, leaf_bsdf_dict
from lightfit.light.face_sampling import FaceSampler
from lightfit.light.leaf_optics import (
    DEFAULT_ROUGHNESS,
    DEFAULT_SPECULAR,
    LeafTraits,
    default_leaf_parameters,
    leaf_bsdf_parameters,
    preset_parameters,
)
from lightfit.light.periodic import DEFAULT_CROSSING_TOLERANCE, PeriodicTracer
from lightfit.plant.mesh import Mesh
from lightfit.plant.periodic import PeriodicCell, compass_vector

if TYPE_CHECKING:
    from lightfit.plant.field import FieldGeometry


#: Radiance of an isotropic (uniform) sky per unit horizontal diffuse irradiance, sr⁻¹: ∫ L cos θ dω = πL
#: over the upper hemisphere.
ISOTROPIC_RADIANCE_PER_DHI = 1.0 / math.pi


def overcast_radiance_per_dhi(cos_zenith):
    r"""Radiance of the CIE standard overcast sky (Moon & Spencer 1942) per unit horizontal diffuse
    irradiance, sr⁻¹, above the horizon: :math:`L = \frac{9}{7\pi}\,\frac{1 + 2\cos\theta_z}{3}`,
    three times brighter at the zenith than at the horizon and normalised so that
    :math:`\int L \cos\theta_z\,d\omega = 1` over the upper hemisphere. Arithmetic only: numpy
    or Dr.Jit arrays (the caller sets 0 below the horizon)."""
    return 9.0 / (7.0 * math.pi) * (1.0 + 2.0 * cos_zenith) / 3.0


def check_sky(sky) -> str:
    """``sky`` if it names a sky model (:data:`SKY_MODELS`), else :class:`InputError` naming ``sky``."""
    if sky not in SKY_MODELS:
        raise InputError(f"unknown sky model {sky!r}", parameter="sky", expected=" or ".join(SKY_MODELS))
    return sky


#: How far a ray's origin leaves the surface it starts from, along the surface normal, m: far below
#: a culm's 1.5 mm radius and the 0.3–0.9 mm between a sheath and its culm.
RAY_OFFSET_M = 1e-5


@dataclass(frozen=True)
class Optics:
    """Optical parameters of the scene, all in [0, 1].

    Attributes:
        specular: leaf glossy reflectance at normal incidence / 0.08 (0.5 → 4 %).
        roughness: leaf microfacet roughness (GGX α = roughness²).
        subsurface: share of the leaf's diffuse light transmitted to the other side.
        base_color: leaf diffuse albedo (grey), not calibrated.
        soil_albedo: Lambertian PAR albedo of the soil (moist loam ≈ 0.1–0.15).

    The defaults are lightfit's default leaf, ``Optics() == Optics.preset("prospect")``: base
    colour and subsurface derived from the PROSPECT-D wheat leaf's PAR reflectance and
    transmittance (:mod:`lightfit.light.leaf_optics`; ≈ 0.067 and 0.60, absorptance 0.90), the
    same leaf as the coupled model's. The reference paper's grey leaf (base colour 0.5, the
    paper's; subsurface 0.3, lightfit's own; absorptance 0.49) is ``Optics.preset("paper")``; other traits
    ``Optics.from_traits(LeafTraits(Cab=40))``.
    """

    specular: float = DEFAULT_SPECULAR
    roughness: float = DEFAULT_ROUGHNESS
    subsurface: float = field(default_factory=lambda: default_leaf_parameters()["subsurface"])
    base_color: float = field(default_factory=lambda: default_leaf_parameters()["base_color"])
    soil_albedo: float = SOIL_ALBEDO

    def __post_init__(self):
        for k, v in asdict(self).items():
            # as a float: np.float32(0.5) would name the same leaf otherwise
            object.__setattr__(self, k, check_fraction(v, k))

    @classmethod
    def from_traits(
        cls,
        traits: LeafTraits | None = None,
        *,
        specular: float = DEFAULT_SPECULAR,
        roughness: float = DEFAULT_ROUGHNESS,
        soil_albedo: float = SOIL_ALBEDO,
    ) -> Optics:
        """Leaf optics whose PAR R and T are PROSPECT-D's for ``traits`` (default: the wheat leaf)."""
        leaf = leaf_bsdf_parameters(LeafTraits() if traits is None else traits, specular=specular, roughness=roughness)
        return cls(**leaf, soil_albedo=soil_albedo)

    @classmethod
    def preset(cls, name: str, **overrides: float) -> Optics:
        """Named optics: ``prospect`` (PROSPECT-D wheat leaf) or ``paper`` (the reference paper's grey
        0.5 leaf); ``overrides`` replace single fields (e.g. ``soil_albedo``)."""
        return cls(**{**preset_parameters(name), "soil_albedo": SOIL_ALBEDO, **overrides})


def sun_vector(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit vector from the ground towards the sun (x east, y north, z up).

    Azimuth is clockwise from north (pvlib convention).
    """
    el = math.radians(elevation_deg)
    return np.append(compass_vector(azimuth_deg) * math.cos(el), math.sin(el))


class FieldScene:
    """A Mitsuba scene of a plant mesh plus the analytic parts of the field: soil, sun and sky.

    Only the plants are Mitsuba geometry (ray intersection, the leaf BSDF). The soil is an
    infinite Lambertian plane z = 0, and the sun and the sky are evaluated analytically by the
    estimator (:mod:`lightfit.light.estimator`): no emitter is instantiated, and the infinite
    soil means a ray leaving the field downwards always meets soil, never the sky.

    With a periodic ``cell`` the mesh is one cell of an infinite field: the Mitsuba geometry
    holds the periodic images of every face that reaches into the cell
    (:meth:`~lightfit.plant.periodic.PeriodicCell.images`) and every ray is cast through
    :attr:`tracer` (:class:`~lightfit.light.periodic.PeriodicTracer`), which wraps rays leaving
    the cell's sides back in through the opposite side. ``mesh`` stays the original faces (the
    estimator samples points on them only, so no area is counted twice).

    Args:
        mesh: the shoot mesh (``lightfit.plant.Mesh``), or a built field
            (:class:`~lightfit.plant.field.FieldGeometry`, what ``lightfit.plant.build`` returns):
            its mesh and, unless ``cell`` is given, its periodic cell. Pass the geometry rather
            than ``geom.mesh``: a periodic field's mesh without its cell is rendered as an
            isolated patch on bare soil, lit from the sides.
        optics: leaf and soil optical parameters (default ``Optics()``, the default leaf).
        sky: ``"isotropic"`` (uniform radiance, default) or ``"overcast"`` (CIE standard
            overcast sky, Moon & Spencer 1942: radiance ∝ 1 + 2 cos θ_z, three times brighter
            at the zenith than at the horizon).
        cell: periodic cell (``Field.cell``), or ``None`` for a finite field on bare soil.
        crossing_tolerance: share of light the periodic crossing cap may truncate
            (:func:`~lightfit.light.periodic.crossing_cap`); periodic scenes only.
    """

    def __init__(
        self,
        mesh: Mesh | FieldGeometry,
        optics: Optics | None = None,
        *,
        sky: str = SKY_MODELS[0],
        cell: PeriodicCell | None = None,
        crossing_tolerance: float = DEFAULT_CROSSING_TOLERANCE,
    ):
        if not isinstance(mesh, Mesh) and hasattr(mesh, "mesh"):  # a FieldGeometry
            mesh, cell = mesh.mesh, mesh.cell if cell is None else cell
        check_sky(sky)
        if mesh.n_faces == 0:
            raise InputError(
                "the mesh has no faces", parameter="mesh", expected="a field with at least one plant segment"
            )
        mi = mitsuba()
        import drjit as dr

        optics = Optics() if optics is None else optics
        if not isinstance(optics, Optics):  # e.g. the name of a preset: an AttributeError further in
            raise InputError(
                f"optics of type {type(optics).__name__}",
                parameter="optics",
                expected='an Optics, e.g. Optics() or Optics.preset("paper")',
            )
        self.mi, self.mesh, self.optics, self.sky, self.cell = mi, mesh, optics, sky, cell
        geometry = mesh if cell is None else cell.images(mesh)
        props = mi.Properties()
        props["bsdf"] = mi.load_dict(
            leaf_bsdf_dict(optics.specular, optics.roughness, optics.subsurface, optics.base_color)
        )
        plants = mi.Mesh("plants", len(geometry.vertices), geometry.n_faces, props, False, False)
        p = mi.traverse(plants)
        p["vertex_positions"] = dr.ravel(mi.Point3f(np.ascontiguousarray(geometry.vertices.T, dtype=np.float32)))
        p["faces"] = dr.ravel(mi.Vector3u(np.ascontiguousarray(geometry.faces.T, dtype=np.uint32)))
        p.update()
        self.scene = mi.load_dict({"type": "scene", "plants": plants})
        self.params = mi.traverse(self.scene)
        self.bsdf = self.scene.shapes()[0].bsdf()
        self.sun = np.array([0.0, 0.0, 1.0])
        #: Ray casting through the periodic cell (``None`` for a finite field).
        self.tracer = (
            None
            if cell is None
            else PeriodicTracer(self.scene, cell, float(mesh.vertices[:, 2].max()), crossing_tolerance)
        )
        self.n_scene_faces = geometry.n_faces  # faces Mitsuba holds (with the periodic images)
        #: The faces Mitsuba holds, in its order (``mesh`` plus, in a periodic cell, the images):
        #: what a ray's ``prim_index`` indexes.
        self.scene_mesh = geometry
        self.freeze_sampling()

    @functools.cached_property
    def face_sampler(self) -> FaceSampler:
        """Area-uniform sample points on this scene's segments (Dr.Jit arrays, built on first use)."""
        return FaceSampler(self.mi, self.mesh)

    def freeze_sampling(self, optics: Optics | None = None) -> None:
        """Draw path directions from the leaf BSDF at ``optics`` (default: the current optics),
        whatever the parameters later set by :meth:`set_optics`.

        Estimates for a fixed seed are then smooth in the leaf parameters, and their derivative
        equals the reverse-mode gradient (see ``LeafBSDF.freeze_sampling``): what finite
        differences and line searches need. Re-freeze near the parameters of interest to keep
        the variance low.
        """
        o = optics or self.optics
        self.bsdf.freeze_sampling(o.specular, o.roughness, o.subsurface)

    def set_sun(self, elevation_deg: float, azimuth_deg: float) -> None:
        """Point the sun (elevation in [−90, 90] and azimuth in degrees); below the horizon its
        part is 0."""
        ok = is_real(elevation_deg) and is_real(azimuth_deg)
        if not (ok and math.isfinite(elevation_deg) and math.isfinite(azimuth_deg) and abs(elevation_deg) <= 90):
            raise InputError(
                f"sun position ({elevation_deg!r}, {azimuth_deg!r})",
                parameter="sun",
                expected="finite numbers of degrees: elevation in [−90, 90] (above 90 is a mirrored sun), azimuth",
            )
        self.sun = sun_vector(elevation_deg, azimuth_deg)

    def sky_radiance(self, cos_zenith):
        """Sky radiance per unit horizontal diffuse irradiance (Dr.Jit Float), 0 below the horizon."""
        import drjit as dr

        if self.sky == "isotropic":
            return dr.select(cos_zenith > 0, mitsuba().Float(ISOTROPIC_RADIANCE_PER_DHI), 0.0)
        return dr.select(cos_zenith > 0, overcast_radiance_per_dhi(cos_zenith), 0.0)

    def scattered_ray(self, si, hit_leaf, p_soil, side, wo, sample2, eps: float = RAY_OFFSET_M):
        """The ray leaving a leaf or soil vertex: ``(origin, direction)``, detached.

        At a leaf (``hit_leaf``) the direction is the leaf's sample ``wo``
        (:meth:`LeafBSDF.sample_direction`, local to the side ``side`` of ``si``); elsewhere, at
        the soil point ``p_soil``, a cosine-weighted direction from ``sample2`` (a Lambertian
        soil). The origin is moved ``eps`` m off the surface, to the side the ray leaves.
        """
        import drjit as dr

        mi = self.mi
        d_leaf = si.to_world(self.bsdf._flip(wo, side))
        side_out = dr.sign(dr.dot(si.n, d_leaf))
        d_soil = mi.Frame3f(mi.Vector3f(0, 0, 1)).to_world(mi.warp.square_to_cosine_hemisphere(sample2))
        o = dr.select(hit_leaf, si.p + eps * side_out * si.n, p_soil + mi.Vector3f(0, 0, eps))
        return o, dr.detach(dr.select(hit_leaf, d_leaf, d_soil))

    def set_optics(self, **leaf: float) -> None:
        """Change leaf parameters (``specular``, ``roughness``, ``subsurface``) in place, no rebuild."""
        for name in leaf:
            if name not in LEAF_PARAMETERS:
                raise InputError(
                    f"unknown leaf parameter {name!r}", parameter=name, expected=", ".join(LEAF_PARAMETERS)
                )
        # every value checked before any is set (a text value was float()'s ValueError)
        leaf = {name: check_fraction(v, name, parameter=name) for name, v in leaf.items()}
        for name, v in leaf.items():
            self.params[f"plants.bsdf.{name}"] = self.mi.Float(v)
        self.params.update()
        self.optics = Optics(**{**asdict(self.optics), **leaf})
