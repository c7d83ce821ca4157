"""Defaults, choices and limits that the command line's help texts state: one home each.

``lightfit --help``, a command's ``--help`` and a usage error build every command's options, whose
help says these values. Read from the modules that use them, they imported JAX, pvlib and pandas
first (seconds before any help): so they live here, in a module that imports nothing, and those
modules import them from here. A value no help text states stays in its own module.
"""

# -- plant ------------------------------------------------------------------------------------

#: Winter wheat at ~270 plants m⁻²: 12.5 cm drill rows (common German practice) and 3 cm
#: within the row (≈ 330 seeds m⁻² sown at ~80 % establishment).
DEFAULT_ROW_SPACING_M = 0.125
DEFAULT_PLANT_SPACING_M = 0.03
#: Largest row or plant spacing a field takes [m]: wider than any crop's rows (maize's are
#: ≈ 0.75 m), so that centimetres given as metres (12.5 for wheat's 0.125) are refused, not grown
#: as plants 12.5 m apart.
MAX_SPACING_M = 2.0
#: Compass azimuth of the rows unless given, degrees: east–west (the rows along x).
DEFAULT_ROW_DIRECTION_DEG = 90.0
#: Plant headings (:attr:`lightfit.plant.Field.headings`): the default first.
HEADINGS = ("random", "aligned")
#: Sheath layouts of :attr:`lightfit.plant.Field.sheaths`; the first is the default.
SHEATHS = ("wrapped", "rods")
#: CPlantBox plant XML grown unless another is named (bundled with lightfit).
DEFAULT_PARAMETER_FILE = "Triticum_aestivum_adapted_2023.xml"
#: The replication's day, which plants are grown to unless another is given; the only day with a
#: bundled forcing (``weather.BUNDLED["2016-04-20"]``).
DEFAULT_DATE = "2016-04-20"
#: Month and day growth starts on unless ``season_start`` is given: the reference paper's 5 March
#: (2016-03-05; the crop was sown in October, and the wheat parameter sets do not describe growth
#: over winter), in the target date's year, so that another year's spring runs as 2016's did.
SEASON_START_MONTH_DAY = (3, 5)
#: Mesh resolution (:class:`lightfit.plant.mesh.MeshResolution`): subdivisions along each segment
#: and across each leaf blade, sides of the stem and sheath prisms.
MESH_ALONG = 1
MESH_ACROSS = 1
MESH_AROUND = 6

# -- light ------------------------------------------------------------------------------------

#: Angular distributions of the diffuse light (:func:`lightfit.light.scene.check_sky`): the default first.
SKY_MODELS = ("isotropic", "overcast")
#: Lambertian PAR albedo of the soil: moist loam, 0.1–0.15 (docs/model.md, "Presets").
SOIL_ALBEDO = 0.12
#: Default rays per m² of ground (all replicates) for the sun and for the sky; see
#: :func:`lightfit.light.projection.check_rays`.
DEFAULT_RAYS_PER_M2 = (2.5e6, 1.0e7)
#: Fewest points per segment of adaptive sampling's first round (8 replicates, what its stopping
#: rule needs): a smaller ``samples`` with a target is raised to it.
MIN_PILOT = 32
#: Most points per segment adaptive sampling spends; segments still above the target there are
#: reported (``samples_per_segment`` = this, ``reached_rse``).
MAX_ADAPTIVE_SAMPLES = 8192
#: Most scattering orders :func:`~lightfit.light.estimator.bounces_for_tolerance` hands out, and the
#: most a render accepts (:func:`~lightfit.light.estimator.check_bounces`): beyond, the leaf or soil
#: albedo is so close to 1 that the series is a modelling error rather than a setting (64 orders
#: leave ρ⁶⁵/(1 − ρ) ≈ 1.1 % of the light out at ρ = 0.9; a PAR leaf's ρ is ≈ 0.2).
MAX_BOUNCES_FOR_TOLERANCE = 64
#: Adaptive sampling's light floor (:func:`lightfit.light.estimator.render_adaptive`'s ``dark_floor``),
#: a fraction of the PAR on a horizontal surface above the canopy: a segment absorbing less than that
#: stops once its *absolute* SE is below ``target_rse`` × that light, instead of chasing a relative
#: error on almost nothing (a culm inside its sheaths, a stem base under the canopy). 0.5 % of full
#: sun (≈ 2 000 µmol m⁻² s⁻¹) is 10 µmol m⁻² s⁻¹, near a wheat leaf's light compensation point.
DARK_FLOOR = 0.005

# -- photosynthesis ---------------------------------------------------------------------------

#: The set used where none is named (``solve``, the coupled model's ``Scenario``).
DEFAULT_PARAMETER_SET = "winter_wheat"

# -- inference --------------------------------------------------------------------------------

#: Emulator design size shared by ``lightfit calibrate`` and ``lightfit posterior`` (same default,
#: same emulator, so one command's design serves the other; :mod:`lightfit.model.emulator`).
DESIGN_SIZE = 20
