"""Every public function of the numerical core under jit, vmap and grad, from one registry.

Each entry registers a public function with ``@case(fn, ...)`` on a builder ``seed -> args``
(the arguments that are traced; static ones are closed over by the entry's ``call``). Generic
tests then apply to every entry, in float64:

* jit and vmap equal eager: ``jit(vmap(call))`` over the examples of two seeds equals the eager
  call on each (eager: under ``jax.disable_jit()``, so that the functions' own inner jits run
  op by op too);
* an entry whose arguments include PRNG keys (``keys``) is a pure function of them: the same
  key gives the same output (eager, twice), the two seeds' different keys different outputs;
* the gradient with respect to the entry's differentiable arguments, along a random direction,
  equals a central finite difference of the same scalar (a fixed random weighting of every
  floating output);
* at the entry's degenerate inputs (a ray on the optical axis, at the edge of the field of view,
  a point behind the camera or at its centre, coincident cameras, a rig without coverage) the
  outputs are finite (or NaN where the function documents NaN as its signal) and the gradients
  are finite.

Each entry compiles one program, ``jit(vmap(value_and_grad))`` (see :func:`_program`), that
serves all of its checks. ``test_every_public_function_is_registered`` lists the public
functions of the covered modules and fails when one is neither registered nor in ``NOT_TRACED``
(with the reason it is not meant to be traced).
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import pkgutil
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import gijax.candidates as cand_pkg
from gijax import numerics
from gijax.baseline import camera_select, cost_filter, matching_cost, rtss, stitch, views, winner
from gijax.candidates import (closed_form, parallax, parametrisation, rig_aware, spacing,
                              uniformity)
from gijax.design import constraints, optimize, spec as design_spec
from gijax.geometry import cameras, field_of_view, occluder, panorama, rig as rig_lib, rotations
from gijax.geometry import panorama_frame, visibility
from gijax.geometry.panorama import Panorama
from gijax.sampling import bilinear_sample, bilinear_sample_zero_padded
from gijax.sweep import consistency, grid, grids, matching, sample, surrogate
from gijax.calibrate import refine as calib_refine
from gijax.nn import cost_volume, layers, refine, regressor, spherical, upsample
from gijax.evaluate import labels, metrics
from gijax.train import losses, unlabeled
from gijax.data import augment, photometric
from gijax.render import views as render_views
from gijax.render.clearance import rig_clearance
from gijax.render.scene import plane_scene, sphere_scene

# gijax.design re-exports the function `objective` under the submodule's name.
objective = importlib.import_module("gijax.design.objective")
# gijax.render re-exports the function `random_scene` under the submodule's name.
render_scene = importlib.import_module("gijax.render.random_scene")

pytestmark = pytest.mark.usefixtures("quick_compiles")

COVERED_PACKAGES = ("gijax.geometry", "gijax.candidates", "gijax.sweep", "gijax.baseline",
                    "gijax.design", "gijax.nn", "gijax.calibrate", "gijax.evaluate")
COVERED_MODULES = ("gijax.train.losses", "gijax.train.unlabeled", "gijax.sampling",
                   "gijax.numerics", "gijax.random_streams", "gijax.data.augment", "gijax.data.photometric",
                   "gijax.render.views", "gijax.render.random_scene")
SEEDS = (0, 1)


# ----------------------------------------------------------------------------------- registry

@dataclasses.dataclass(frozen=True)
class Case:
    label: str
    fn: Callable
    call: Callable  # traced args -> output
    build: Callable  # seed -> tuple of traced args
    diff: tuple  # positions of the differentiable arguments
    degenerate: tuple  # ((name, builder () -> args, NaN outputs documented), ...)
    rtol: float
    atol: float
    fd_tol: float
    keys: tuple  # positions of the PRNG-key arguments (the output is a pure function of them)


REGISTRY: dict[str, Case] = {}


def case(fn, call=None, diff=(), degenerate=(), label=None, rtol=1e-7, atol=1e-9, fd_tol=1e-5,
         keys=()):
    """Register ``fn`` with the decorated builder ``seed -> args``; ``call(*args)`` (default
    ``fn``) is what the generic tests transform."""

    def wrap(build):
        name = label or f"{fn.__module__}.{fn.__name__}"
        assert name not in REGISTRY, name
        REGISTRY[name] = Case(name, fn, call or fn, build, tuple(diff), tuple(degenerate), rtol,
                              atol, fd_tol, tuple(keys))
        return build

    return wrap


def public_name(fn) -> str:
    return f"{fn.__module__}.{fn.__name__}"


# Public functions that are not meant to be traced, each with the reason (their docstrings say
# so too). Argument checks raise on concrete values and return nothing; reports and files
# return Python values; builders turn names or static sizes into constants.
NOT_TRACED = {
    "gijax.train.unlabeled.stored_objective": "fills in a stored dict of weights",
    # argument checks
    "gijax.candidates.validation.is_concrete": "inspects whether values are traced",
    "gijax.nn.regressor.check_estimate": "argument check (raises on a name or window)",
    "gijax.candidates.validation.require": "argument check (raises, or a checkify debug check)",
    "gijax.candidates.validation.check_count": "argument check of a static count",
    "gijax.candidates.validation.check_range": "argument check",
    "gijax.candidates.validation.check_baseline": "argument check",
    "gijax.candidates.validation.check_candidates": "eager check of a concrete list (NumPy out)",
    "gijax.candidates.validation.guard_candidates": "argument check",
    "gijax.candidates.rig_aware.require_coverage": "argument check",
    "gijax.sweep.surrogate.check_images": "shape check (raises, returns nothing)",
    "gijax.evaluate.metrics.check_metric_set": "validates a metric-set name",
    # reports, files, Python values
    "gijax.geometry.cameras.camera_params": "Python floats for printing and files",
    "gijax.geometry.rig.pairwise_baselines": "NumPy report of concrete poses",
    "gijax.geometry.rig.describe_rig": "text report",
    "gijax.geometry.field_of_view.describe_field_of_view": "text report",
    "gijax.geometry.rig.is_homogeneous": "structural query: a Python bool from static fields",
    "gijax.geometry.panorama_frame.choose_panorama": "NumPy choice from concrete poses",
    "gijax.geometry.panorama_frame.estimate_up": "NumPy report of concrete poses",
    "gijax.geometry.panorama_frame.describe_choice": "text report",
    "gijax.geometry.panorama_frame.panorama_of": "a static panorama from static sizes",
    "gijax.geometry.panorama_frame.coverage_of": "a name from a static panorama",
    "gijax.sweep.grids.cost_panorama": "a static panorama from a static panorama",
    "gijax.design.constraints.constraint_report": "plain-Python summary",
    "gijax.design.figure.plot_design": "writes a PNG",
    "gijax.design.optimize.terms_to_python": "floats and lists for reports",
    "gijax.design.optimize.evaluate_layouts": "chunked evaluation loop with NumPy output",
    "gijax.design.optimize.optimize_layout": "search loop (progress bar, Python results)",
    "gijax.design.optimize.random_search": "search loop",
    "gijax.design.optimize.adam_step": "builds an optimiser and its compiled step (cached)",
    "gijax.design.optimize.grid_search": "search loop",
    "gijax.design.optimize.grid_points": "NumPy lattice of a static spec",
    "gijax.design.optimize.regular_layout": "NumPy geometry of a static spec",
    "gijax.design.optimize.layout_rig": "a concrete rig with rendered masks (an input edge)",
    "gijax.baseline.rtss.get_rtss_preset": "lookup of static settings by name",
    "gijax.baseline.rtss.choose_candidates": "command-line spec (names, files) to NumPy",
    "gijax.candidates.spec.read_candidate_file": "reads a file",
    "gijax.candidates.spec.resolve_candidates": "command-line spec (names, files) to NumPy",
    "gijax.candidates.spec.model_candidates": "command-line spec (names, files) to NumPy",
    "gijax.baseline.rtss.rtss_predict_sample": "NumPy outputs for one loaded sample",
    "gijax.calibrate.refine.check_texture": "argument check of concrete measures",
    "gijax.calibrate.refine.check_overlap": "argument check of concrete measures",
    "gijax.calibrate.refine.frame_texture": "NumPy report of a concrete frame",
    "gijax.calibrate.refine.frame_overlap": "Python float of a concrete frame",
    "gijax.calibrate.refine.initial_inverse_distance": "NumPy start from the baseline (an edge)",
    "gijax.calibrate.refine.refine_rig": "optimisation loop (progress bar, Python results)",
    "gijax.calibrate.refine.transfer_refinement": "a concrete rig from refined values",
    "gijax.calibrate.refine.pose_change": "NumPy report of concrete poses",
    "gijax.calibrate.refine.refine_scale": "Python float of a concrete image width",
    "gijax.calibrate.refine.implausible_moves": "text lines from a concrete report",
    "gijax.calibrate.refine.round_move_line": "a text line from a concrete report",
    "gijax.calibrate.refine.gauge_aligned_errors": "NumPy report of concrete poses",
    "gijax.calibrate.refine.align_gauge": "NumPy report of concrete poses",
    "gijax.calibrate.refine.blur_radius": "Python int of a static sigma",
    "gijax.calibrate.refine.refine_panorama": "a static panorama from concrete poses",
    "gijax.calibrate.frames.read_frame_folder": "reads files",
    "gijax.calibrate.frames.read_frames": "reads files",
    "gijax.calibrate.plots.plot_loss_curve": "writes a PNG",
    "gijax.calibrate.constraint.neighbour_colouring": "NumPy constant of a static size",
    "gijax.calibrate.constraint.gauge_basis": "NumPy basis of concrete poses",
    "gijax.calibrate.constraint.pose_constraint": "NumPy report of concrete frames (an edge)",
    "gijax.calibrate.constraint.constraint_report": "NumPy report of concrete curvatures",
    "gijax.calibrate.constraint.weak_constraint_lines": "text lines from a concrete report",
    "gijax.calibrate.constraint.constraint_lines": "text lines from a concrete report",
    "gijax.evaluate.metrics.summarize": "Python numbers from accumulated values",
    "gijax.evaluate.metrics.evaluate_batch": "Python numbers",
    "gijax.evaluate.loop.evaluate_predictions": "evaluation loop over batches (Python numbers)",
    # constants of static arguments (nothing to trace)
    "gijax.geometry.cameras.pixel_grid": "constant of static image sizes",
    "gijax.geometry.panorama.lonlat_grid": "constant of a static panorama",
    "gijax.geometry.panorama.ray_grid": "constant of a static panorama",
    "gijax.candidates.parallax.rays_and_solid_angles": "constant of a static panorama",
    "gijax.geometry.layouts.synthetic_camera": "camera from static numbers",
    "gijax.geometry.layouts.builtin_rig": "rig from a name",
    "gijax.geometry.layouts.layout_rig": "rig from NumPy positions (an input edge)",
    "gijax.design.objective.design_camera": "camera of a static spec",
    "gijax.evaluate.metrics.gaussian_window_1d": "NumPy constant of static sizes",
    "gijax.numerics.tiny": "Python float of a dtype",
    "gijax.numerics.guard_floor": "Python float of a dtype",
    "gijax.numerics.float_dtype": "a dtype",
    # network building: modules, parameter counts, weight import and static tap tables (the
    # modules themselves are checked under jit and grad in test_nn.py and test_model.py)
    "gijax.nn.build.make_cost_volume": "builds a module from a config",
    "gijax.nn.build.make_unet": "builds a module from a config",
    "gijax.nn.build.make_matching_skip": "builds a module from a config",
    "gijax.nn.layers.batch_norm": "builds a module",
    "gijax.nn.layers.conv": "builds a module",
    "gijax.nn.layers.param_count": "Python int of a module",
    "gijax.nn.presets.get_preset": "config lookup by name",
    "gijax.nn.release_weights.convert_state_dict": "NumPy weight import",
    "gijax.nn.release_weights.check_shapes": "argument check of NumPy weights",
    "gijax.nn.release_weights.load_state_dict": "fills a module from NumPy weights",
    "gijax.nn.spherical.tangent_offsets": "NumPy constant of static sizes",
    "gijax.nn.spherical.release_offsets": "NumPy constant of static sizes",
    "gijax.nn.spherical.release_positions": "NumPy constant of static offsets",
    "gijax.nn.spherical.sampling_tables": "NumPy constant of static offsets",
    "gijax.nn.spherical.zero_padded_tables": "NumPy constant of static positions",
    "gijax.nn.spherical.transposed_tables": "NumPy constant of static tables",
    # the named random streams (host-side seeding) and augmentation's NumPy mask edits
    "gijax.random_streams.entropy": "Python integers of integer seeds",
    "gijax.random_streams.host_rng": "NumPy generator of integer seeds",
    "gijax.random_streams.device_key": "a key from integer seeds (NumPy SeedSequence)",
    "gijax.data.augment.erase_rectangle": "NumPy mask edit from a NumPy generator",
    "gijax.data.augment.augment_masks": "NumPy mask augmentation from a NumPy generator",
    "gijax.data.augment.augment_preset": "config lookup by name",
    "gijax.data.photometric.dct_matrix": "NumPy constant of a static size",
}

# Traced public functions whose checks live in another test file, because one compilation of
# theirs costs more than this module's budget allows (a whole random scene: about 25 s to
# compile under vmap, over a minute op by op under disable_jit).
TESTED_ELSEWHERE = {
    "gijax.render.random_scene.random_scene":
        "test_render.py: pure jittable function of the key, keyed draws",
    "gijax.render.random_scene.scene_program":
        "takes the named draws of run_with_draws; traced through random_scene (test_render.py)",
    "gijax.render.views.random_sample_scene":
        "test_render.py::test_sample_scene_is_a_pure_jittable_function_of_the_key",
    "gijax.render.views.random_sample":
        "test_render.py::test_deterministic_from_seed_and_seeds_differ",
    "gijax.calibrate.constraint.pose_information":
        "test_calibrate.py: jitted, against a dense Gauss-Newton assembly in float64 (op by op "
        "its second-order passes take 20 s)",
    "gijax.render.views.render_views":
        "test_render.py: multi-view consistency, determinism (float32 only: its scan carries "
        "float32 rays)",
}


def public_functions() -> dict[str, Callable]:
    """Public functions defined in the covered modules (jitted ones included)."""
    mods = [importlib.import_module(m) for m in COVERED_MODULES]
    for pkg_name in COVERED_PACKAGES:
        pkg = importlib.import_module(pkg_name)
        mods.append(pkg)
        mods += [importlib.import_module(f"{pkg_name}.{m.name}")
                 for m in pkgutil.iter_modules(pkg.__path__)]
    out = {}
    for mod in mods:
        for name, obj in vars(mod).items():
            target = inspect.unwrap(obj) if callable(obj) else obj
            if (not name.startswith("_") and inspect.isfunction(target)
                    and target.__module__ == mod.__name__):
                out[f"{mod.__name__}.{name}"] = obj
    return out


def test_every_public_function_is_registered():
    registered = {public_name(inspect.unwrap(c.fn)) for c in REGISTRY.values()}
    excluded = set(NOT_TRACED) | set(TESTED_ELSEWHERE)
    missing = sorted(set(public_functions()) - registered - excluded)
    assert not missing, f"public functions neither registered nor excluded: {missing}"
    stale = sorted(excluded - set(public_functions()))
    assert not stale, f"exclusions that name no public function: {stale}"
    both = sorted(excluded & registered) + sorted(set(NOT_TRACED) & set(TESTED_ELSEWHERE))
    assert not both, f"registered and excluded at once: {both}"
    # The packages' own __all__ lists name only things that exist.
    for pkg_name in COVERED_PACKAGES:
        pkg = importlib.import_module(pkg_name)
        assert all(hasattr(pkg, n) for n in pkg.__all__), pkg_name


def test_numerics_values_and_dtype_floors():
    with jax.enable_x64(True):
        for dt in (np.float32, np.float64):
            floor = float(np.sqrt(np.finfo(dt).tiny))
            assert numerics.guard_floor(np.zeros(1, dt)) == pytest.approx(floor, rel=1e-12)
            x = jnp.asarray([4.0, 0.0, -1.0], dt)
            np.testing.assert_allclose(numerics.safe_sqrt(x), [2.0, np.sqrt(floor),
                                                               np.sqrt(floor)], rtol=1e-6)
            np.testing.assert_array_equal(numerics.sqrt_or_zero(x), [2.0, 0.0, 0.0])
            np.testing.assert_allclose(numerics.safe_div(jnp.asarray([3.0, 3.0], dt),
                                                         jnp.asarray([2.0, 0.0], dt)), [1.5, 0.0])
            np.testing.assert_allclose(numerics.unit(jnp.asarray([[3.0, 4.0], [0.0, 0.0]], dt)),
                                       [[0.6, 0.8], [0.0, 0.0]], rtol=1e-6)
            np.testing.assert_array_equal(numerics.away_from_zero(jnp.asarray([0.0, -0.0, -2.0],
                                                                              dt)),
                                          np.asarray([floor, floor, -2.0], dt))
            np.testing.assert_array_equal(numerics.safe_denominator(jnp.asarray([0.0, 2.0], dt)),
                                          [1.0, 2.0])
            # Zero gradients where a guard replaced the value; the exact ones elsewhere.
            g = jax.grad(lambda v: numerics.safe_norm(v))(jnp.asarray([0.0, 0.0], dt))
            np.testing.assert_array_equal(g, [0.0, 0.0])
            g = jax.grad(lambda v: numerics.safe_norm(v))(jnp.asarray([3.0, 4.0], dt))
            np.testing.assert_allclose(g, [0.6, 0.8], rtol=1e-6)
            g = jax.grad(lambda d: numerics.safe_div(1.0, d))(jnp.asarray(0.0, dt))
            assert float(g) == 0.0
        assert numerics.float_dtype(jnp.zeros(1, jnp.bfloat16)) == jnp.float32
        assert numerics.float_dtype(jnp.zeros(1, jnp.float64)) == jnp.float64


# ------------------------------------------------------------------------------- fixtures

F64 = jnp.float64
SIZE, FOCAL = 16, 300.0 / 64.0  # the dataset's lens on a 16-pixel image
PANO = Panorama.hemisphere(2, 4)
FEATURE_PANO = Panorama.hemisphere(4, 8)
VIEW = views.MatchView("fisheye", 8)
SPEC = design_spec.DesignSpec(num_cameras=3, pano=PANO, num_candidates=4, samples=2,
                              camera_size=SIZE, focal=FOCAL, orientations=True, heights=True)
RTSS_CONFIG = rtss.RTSSConfig(num_candidates=4, match_size=8, cost="ad", cost_window=1,
                              filter_levels=1, stitch_samples=4, fill_iterations=1)


@functools.lru_cache(maxsize=None)
def lens(seed, model="equidistant"):
    j = 0.02 * seed
    base = dict(fx=FOCAL * (1 + j), fy=FOCAL * (1 - j), cx=7.5 + j, cy=7.5 - j)
    extra = {"ds": dict(xi=-0.2 + j, alpha=0.59 - j), "eucm": dict(alpha=0.6 + j, beta=1.1 - j),
             "kb": dict(k1=0.02 + j, k2=-0.01, k3=0.003, k4=-0.001), "equidistant": {},
             "omni": dict(xi=1.1 + j, k1=-0.2 + j, k2=0.04, p1=3e-3, p2=-2e-3 + j)}[model]
    return cameras.make_camera(model, {**base, **extra}, SIZE, SIZE, 195.0, dtype=F64)


@functools.lru_cache(maxsize=None)
def small_rig(seed, n=2, reference="centroid", occluded=False):
    rng = np.random.default_rng(100 + seed)
    ang = np.deg2rad(90.0 + 360.0 * np.arange(n) / n) + 0.05 * rng.normal(size=n)
    t = np.stack([0.2 * np.cos(ang), 0.2 * np.sin(ang), 0.01 * rng.normal(size=n)], -1)
    rot = np.asarray(rotations.axis_angle_to_matrix(jnp.asarray(0.05 * rng.normal(size=(n, 3)))))
    ref = t.mean(0) if reference == "centroid" else t[0] + [0.0, 0.0, 0.0]
    occ = occluder.Cylinder(*(jnp.asarray(v, F64) for v in (0.0, 0.0, 0.03, 0.0, 0.05))) \
        if occluded else None
    return rig_lib.make_rig([lens(seed) for _ in range(n)], rot, t, ref, occluder=occ, dtype=F64)


@functools.lru_cache(maxsize=None)
def coincident_rig(n=2):
    """Every camera at the origin: no parallax anywhere (no coverage)."""
    return rig_lib.make_rig([lens(0) for _ in range(n)], np.tile(np.eye(3), (n, 1, 1)),
                            np.zeros((n, 3)), dtype=F64)


@functools.lru_cache(maxsize=None)
def candidates(seed, n=4):
    c = np.geomspace(0.5, 100.0, n)
    c[1:-1] *= 1.0 + 0.03 * seed
    return jnp.asarray(c, F64)


@functools.lru_cache(maxsize=None)
def points(seed, count=5):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(count, 3)) * [0.5, 0.5, 0.2] + [0.0, 0.0, 1.0]
    return jnp.asarray(p, F64)


@functools.lru_cache(maxsize=None)
def image(seed, h=SIZE, w=SIZE, c=3):
    return jnp.asarray(np.random.default_rng(seed).uniform(0.1, 0.9, (h, w, c)), F64)


@functools.lru_cache(maxsize=None)
def layout(seed):
    rng = np.random.default_rng(200 + seed)
    ang = np.deg2rad([90.0, 210.0, 330.0]) + 0.1 * rng.normal(size=3)
    pos = 0.35 * np.stack([np.cos(ang), np.sin(ang)], -1)
    return design_spec.make_layout(pos, heights=0.05 + 0.02 * rng.uniform(size=3),
                                   rotvecs=0.1 * rng.normal(size=(3, 3)), dtype=F64)


# Directions at the degenerate places of a camera: on the optical axis, at the edge of the
# 195-degree field of view, behind it, at the camera centre.
EDGE = np.deg2rad(97.5)
DEGENERATE_POINTS = np.array([[0.0, 0.0, 1.0], [np.sin(EDGE), 0.0, np.cos(EDGE)],
                              [0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [1e-30, 0.0, 1.0]])


def degenerate_points():
    return jnp.asarray(DEGENERATE_POINTS, F64)


# ------------------------------------------------------------------------------ numerics

for _fn in (numerics.safe_sqrt, numerics.sqrt_or_zero):
    case(_fn, diff=(0,), degenerate=[("zero and below", lambda: (jnp.asarray([0.0, -1.0, 1e-300],
                                                                               F64),), False)])(
        lambda seed: (jnp.asarray([0.3, 2.0 + seed, 1e-3], F64),))

for _fn in (numerics.safe_norm, numerics.unit):
    case(_fn, diff=(0,), degenerate=[("zero vector", lambda: (jnp.zeros((2, 3), F64),), False)])(
        lambda seed: (points(seed, 2),))


@case(numerics.safe_div, diff=(0, 1),
      degenerate=[("zero denominator", lambda: (jnp.ones(2, F64), jnp.zeros(2, F64)), False)])
def _safe_div(seed):
    return jnp.asarray([1.0, -2.0 - seed], F64), jnp.asarray([0.5, 3.0], F64)


@case(numerics.safe_denominator, diff=(0,),
      degenerate=[("zero", lambda: (jnp.zeros(2, F64),), False)])
def _safe_denominator(seed):
    return (jnp.asarray([0.5 + seed, 3.0], F64),)


@case(numerics.away_from_zero, diff=(0,),
      degenerate=[("zero", lambda: (jnp.asarray([0.0, -0.0], F64),), False)])
def _away_from_zero(seed):
    return (jnp.asarray([0.5 + seed, -3.0], F64),)


# ------------------------------------------------------------------------------ geometry

# Every camera model gijax has: a new model gets every camera property without a new line here.
LENS_MODELS = tuple(cameras.CAMERA_MODELS)

for _model in LENS_MODELS:
    case(cameras.project, diff=(0, 1), label=f"project[{_model}]",
         degenerate=[("axis, fov edge, behind, centre",
                      functools.partial(lambda m: (lens(0, m), degenerate_points()), _model),
                      False)])(
        functools.partial(lambda m, seed: (lens(seed, m), points(seed)), _model))
    case(cameras.unproject, diff=(0, 1), label=f"unproject[{_model}]",
         degenerate=[("principal point and far outside",
                      functools.partial(lambda m: (lens(0, m), jnp.asarray(
                          [[7.5, 7.5], [500.0, -300.0], [7.5 + 1e-12, 7.5], [-1e4, 8.0],
                           [7.5, 1e5]], F64)), _model),
                      False)])(
        functools.partial(lambda m, seed: (lens(seed, m), jnp.asarray(
            np.random.default_rng(seed).uniform(2.0, 13.0, (5, 2)), F64)), _model))


def _off_centre(seed, model):
    """``lens`` with its principal point off the image centre: the nearest side and the
    farthest corner are then unique (with ties the field of view has a kink there)."""
    return (dataclasses.replace(lens(seed, model), cx=jnp.asarray(7.0 + 0.1 * seed, F64),
                                cy=jnp.asarray(8.2 - 0.1 * seed, F64)),)


LIMIT_DEGENERATE = {
    m: [("alpha = 0.5: the limit is the backward axis", functools.partial(
        lambda m: (dataclasses.replace(lens(0, m), alpha=jnp.asarray(0.5, F64)),), m), False)]
    for m in ("ds", "eucm")}
LIMIT_DEGENERATE["omni"] = [
    ("xi = 1 without a fold: the limit is the backward axis", lambda: (dataclasses.replace(
        lens(0, "omni"), xi=jnp.asarray(1.0, F64), k1=jnp.asarray(0.0, F64)),), False),
    ("k2 = 0: the fold from k1 alone", lambda: (dataclasses.replace(
        lens(0, "omni"), k2=jnp.asarray(0.0, F64)),), False)]



def _limit_args(model, seed):
    cam = lens(seed, model)
    if model == "omni":  # the radial distortion folds inside the sphere's limit (r^2 = 2)
        cam = dataclasses.replace(cam, k2=jnp.asarray(0.01, F64))
    return (cam,)


for _model in LENS_MODELS:
    case(field_of_view.field_of_view, diff=(0,), label=f"field_of_view[{_model}]")(
        functools.partial(lambda m, seed: _off_centre(seed, m), _model))
    case(field_of_view.model_limit, diff=(0,), label=f"model_limit[{_model}]",
         degenerate=LIMIT_DEGENERATE.get(_model, []))(
        functools.partial(_limit_args, _model))


def _field_mask():
    """A mask whose widest pixel is unique for every ``_off_centre`` lens (no kink of the max)."""
    mask = np.zeros((SIZE, SIZE), np.float64)
    mask[2:12, 3:14] = 1.0
    mask[12, 13] = 1.0
    return jnp.asarray(mask)


for _model in LENS_MODELS:
    case(field_of_view.mask_field_of_view, diff=(0,), label=f"mask_field_of_view[{_model}]")(
        functools.partial(lambda m, seed: (*_off_centre(seed, m), _field_mask()), _model))


@case(cameras.make_camera, call=lambda p: cameras.make_camera("ds", p, SIZE, SIZE, 195.0,
                                                             dtype=F64), diff=(0,))
def _make_camera(seed):
    return ({"fx": jnp.asarray(4.0 + seed, F64), "fy": jnp.asarray(4.5, F64),
             "cx": jnp.asarray(7.5, F64), "cy": jnp.asarray(7.0, F64),
             "xi": jnp.asarray(-0.2, F64), "alpha": jnp.asarray(0.6, F64)},)


@case(cameras.scale_camera, call=lambda c: cameras.scale_camera(c, 0.5), diff=(0,))
def _scale_camera(seed):
    return (lens(seed, "ds"),)


@case(rotations.skew, diff=(0,))
def _skew(seed):
    return (points(seed, 2),)


@case(rotations.axis_angle_to_matrix, diff=(0,),
      degenerate=[("zero rotation", lambda: (jnp.zeros((2, 3), F64),), False)])
def _axis_angle(seed):
    return (0.3 * points(seed, 2),)


@functools.lru_cache(maxsize=None)
def _rays_and_origins(seed):
    rng = np.random.default_rng(seed)
    o = jnp.asarray(rng.normal(size=(4, 3)) * [0.3, 0.3, 0.0] + [0.0, 0.0, 0.02], F64)
    d = numerics.unit(jnp.asarray(rng.normal(size=(4, 3)) + [0.0, 0.0, 0.3], F64))
    return o, d


@functools.lru_cache(maxsize=None)
def _cylinder(seed):
    return occluder.Cylinder(*(jnp.asarray(v, F64) for v in (0.01 * seed, 0.0, 0.05, 0.0, 0.1)))


CYLINDER_DEGENERATE = [("tangent, vertical, inside, on the cap's rim", lambda: (
    _cylinder(0), jnp.asarray([[-1.0, 0.05, 0.05], [0.3, 0.0, -1.0], [0.0, 0.0, 0.05],
                               [0.05, 0.0, -1.0]], F64),
    jnp.asarray([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], F64)),
    False)]


@case(occluder.cylinder_hit, diff=(0, 1, 2), degenerate=CYLINDER_DEGENERATE)
def _cylinder_hit(seed):
    return (_cylinder(seed), *_rays_and_origins(seed))


@case(occluder.cylinder_intersection, diff=(0, 1, 2), degenerate=CYLINDER_DEGENERATE)
def _cylinder_intersection(seed):
    return (_cylinder(seed), *_rays_and_origins(seed))


@case(visibility.visible_from, call=lambda p, c: visibility.visible_from(p, c, 8),
      diff=(0, 1), degenerate=[("point at the viewpoint, on the pole", lambda: (
          jnp.asarray([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0], [0.0, 0.0, 3.0]], F64),
          jnp.zeros(3, F64)), False)])
def _visible_from(seed):
    return points(seed, 6), jnp.asarray([0.1 * seed, -0.05, 0.02], F64)


@case(panorama.lonlat_to_direction, diff=(0, 1))
def _lonlat_to_direction(seed):
    return jnp.asarray([0.3, -2.0 + seed], F64), jnp.asarray([-1.2, -0.1], F64)


@case(panorama.direction_to_lonlat, diff=(0,),
      degenerate=[("pole and zero", lambda: (jnp.asarray([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0],
                                                          [0.0, 0.0, -2.0]], F64),), False)])
def _direction_to_lonlat(seed):
    return (points(seed, 3),)


@case(panorama.direction_to_pixel, call=lambda d: panorama.direction_to_pixel(PANO, d),
      diff=(0,), degenerate=[("pole", lambda: (jnp.asarray([[0.0, 0.0, 1.0], [0.0, 0.0, 3.0],
                                                            [1e-200, 0.0, 1.0]], F64),), False)])
def _direction_to_pixel(seed):
    return (points(seed, 3),)


@case(panorama.pixel_to_direction, call=lambda p: panorama.pixel_to_direction(PANO, p),
      diff=(0,))
def _pixel_to_direction(seed):
    return (jnp.asarray([[0.5 + seed, 0.2], [3.1, 1.4]], F64),)


def framed_rig(seed):
    """A small rig whose panorama frame is turned away from its +z axis."""
    turn = rotations.axis_angle_to_matrix(jnp.asarray([0.4, -0.3 + 0.1 * seed, 0.9], F64))
    return panorama_frame.with_panorama_rotation(small_rig(seed), turn)


@case(panorama_frame.panorama_rotation, diff=(0,))
def _panorama_rotation(seed):
    return (framed_rig(seed),)


@case(panorama_frame.panorama_rays, call=lambda r: panorama_frame.panorama_rays(r, PANO),
      diff=(0,))
def _panorama_rays(seed):
    return (framed_rig(seed),)


@case(panorama_frame.to_panorama_frame, diff=(0, 1))
def _to_panorama_frame(seed):
    return framed_rig(seed), points(seed, 3)


@case(panorama_frame.panorama_pixels,
      call=lambda r, d: panorama_frame.panorama_pixels(r, PANO, d), diff=(0, 1))
def _panorama_pixels(seed):
    return framed_rig(seed), points(seed, 3)


@case(panorama_frame.frame_from_up, diff=(0, 1))
def _frame_from_up(seed):
    return jnp.asarray([0.1, -0.2 + seed, 1.3], F64), jnp.asarray([1.0, 0.3, -0.2], F64)


@case(panorama_frame.with_panorama_rotation, diff=(0, 1))
def _with_panorama_rotation(seed):
    return small_rig(seed), rotations.axis_angle_to_matrix(jnp.asarray([0.2, 0.5, -0.1 * seed],
                                                                       F64))


@case(rig_lib.make_rig, call=lambda r, t: rig_lib.make_rig([lens(0), lens(0)], r, t, dtype=F64),
      diff=(0, 1))
def _make_rig(seed):
    r = small_rig(seed)
    return r.rotations, r.translations


for _fn in (rig_lib.rig_to_camera, rig_lib.camera_to_rig):
    case(_fn, call=functools.partial(lambda f, r, p: f(r, 1, p), _fn), diff=(0, 1))(
        lambda seed: (small_rig(seed), points(seed)))


@case(rig_lib.map_cameras, call=lambda r: rig_lib.map_cameras(
    lambda cam, rot, t, mask: rot @ t * cam.fx + jnp.sum(mask), r), diff=(0,))
def _map_cameras(seed):
    return (small_rig(seed),)


@case(rig_lib.project_rig_points, diff=(0, 1))
def _project_rig_points(seed):
    return small_rig(seed), points(seed)


@case(rig_lib.occlusion_mask, call=lambda r: rig_lib.occlusion_mask(r, 1))
def _occlusion_mask(seed):
    return (small_rig(seed, occluded=True),)


@case(rig_lib.with_occlusion_masks, call=lambda r: rig_lib.with_occlusion_masks(r).masks)
def _with_occlusion_masks(seed):
    return (small_rig(seed, occluded=True),)


@case(rig_lib.scale_rig, call=lambda r: rig_lib.scale_rig(rig_lib.with_occlusion_masks(r), 0.5),
      diff=(0,))
def _scale_rig(seed):
    return (small_rig(seed, occluded=True),)


# ------------------------------------------------------------------------------ candidates

@case(closed_form.ev_candidates, call=lambda lo, hi: closed_form.ev_candidates(5, lo, hi),
      diff=(0, 1))
def _ev(seed):
    return jnp.asarray(0.5 + 0.1 * seed, F64), jnp.asarray(100.0, F64)


@case(closed_form.gi_candidates, call=lambda lo, hi, b: closed_form.gi_candidates(5, lo, hi, b),
      diff=(0, 1, 2))
def _gi(seed):
    return jnp.asarray(0.5, F64), jnp.asarray(90.0 + seed, F64), jnp.asarray(0.3, F64)


@case(parametrisation.candidates_from_logits, diff=(0, 1, 2))
def _candidates_from_logits(seed):
    return (jnp.asarray([0.3, -1.0 + seed, 0.7, 0.1], F64), jnp.asarray(0.5, F64),
            jnp.asarray(40.0 + seed, F64))


@case(parametrisation.logits_from_candidates, diff=(0,))
def _logits_from_candidates(seed):
    return (jnp.asarray([0.5, 0.8 + 0.1 * seed, 1.7, 6.0, 100.0], F64),)


@case(closed_form.closed_form_steps, diff=(0, 1))
def _closed_form_steps(seed):
    return candidates(seed), jnp.asarray(0.3, F64)


@case(cand_pkg.candidates_for, call=lambda r: cand_pkg.candidates_for("gi", 4, r, pano=PANO),
      diff=(0,))
def _candidates_for(seed):
    return (small_rig(seed),)


@case(cand_pkg.recomputed_candidates,
      call=lambda r: cand_pkg.recomputed_candidates("spacing", 4, r), diff=(0,))
def _recomputed(seed):
    return (small_rig(seed),)


@case(rig_aware.as_float_rig, diff=(0,))
def _as_float_rig(seed):
    return (small_rig(seed),)


@case(rig_aware.rig_terms, call=lambda r, lo: rig_aware.rig_terms(r, lo, 100.0, PANO, samples=2),
      diff=(0, 1))
def _rig_terms(seed):
    return small_rig(seed), jnp.asarray(0.5, F64)


_terms_jit = jax.jit(lambda r: rig_aware.rig_terms(r, 0.5, 100.0, PANO, samples=2))


@functools.lru_cache(maxsize=None)
def _terms(seed):
    return _terms_jit(small_rig(seed))


for _fn in (rig_aware.parallax_angles, rig_aware.cumulative_displacement,
            rig_aware.cumulative_displacement_slope):
    case(_fn, diff=(0, 1))(lambda seed: (_terms(seed), jnp.asarray([0.01, 0.4 + seed], F64)))


NO_COVERAGE = [("no coverage", lambda: (coincident_rig(),), True)]


@case(rig_aware.solve_equal_steps,
      call=lambda t, lo: rig_aware.solve_equal_steps(t, 4, lo, 100.0), diff=(0, 1),
      degenerate=[("no coverage", lambda: (jax.tree_util.tree_map(jnp.zeros_like, _terms(0)),
                                           jnp.asarray(0.5, F64)), True)])
def _solve(seed):
    return _terms(seed), jnp.asarray(0.5, F64)


@case(rig_aware.rig_gi_candidates,
      call=lambda r: rig_aware.rig_gi_candidates(r, 4, pano=PANO, samples=2), diff=(0,),
      degenerate=NO_COVERAGE)
def _rig_gi(seed):
    return (small_rig(seed),)


@case(rig_aware.fit_closed_form_baseline, diff=(0,), fd_tol=1e-4)
def _fit(seed):
    return (closed_form.gi_candidates(6, baseline=0.3 + 0.1 * seed)
            * jnp.asarray([1, 1.01, 0.99, 1.02, 1.0, 1], F64),)


@case(rig_aware.effective_baseline,
      call=lambda r: rig_aware.effective_baseline(r, 5, pano=PANO, samples=2), diff=(0,),
      degenerate=NO_COVERAGE, fd_tol=1e-4)
def _effective_baseline(seed):
    return (small_rig(seed, reference="camera"),)


@case(parallax.sample_distances, call=lambda lo, hi: parallax.sample_distances(lo, hi, 3, F64),
      diff=(0, 1))
def _sample_distances(seed):
    return jnp.asarray(0.5 + seed, F64), jnp.asarray(50.0, F64)


def _offsets(seed):
    r = small_rig(seed)
    return r.reference, r.translations, numerics.unit(points(seed, 3))


@case(parallax.parallax_offsets, diff=(0, 1, 2),
      degenerate=[("camera at the reference", lambda: (jnp.zeros(3, F64), jnp.zeros((2, 3), F64),
                                                       numerics.unit(points(0, 3))), False)])
def _parallax_offsets(seed):
    return _offsets(seed)


@case(parallax.closest_approach, call=lambda p, q: parallax.closest_approach(p, q, 0.5, 100.0),
      diff=(0, 1), degenerate=[("through the centre", lambda: (jnp.asarray([-1.0, 0.0], F64),
                                                              jnp.zeros(2, F64)), False)])
def _closest(seed):
    return jnp.asarray([0.1, -0.3 - seed], F64), jnp.asarray([0.2, 0.1], F64)


@case(parallax.motion_directions, diff=(0, 1, 2, 3),
      degenerate=[("no parallax", lambda: (jnp.zeros((2, 3), F64), jnp.zeros((2, 3), F64),
                                            jnp.zeros((2, 3), F64), numerics.unit(points(0, 3))),
                   False)])
def _motion(seed):
    ref, t, rays = _offsets(seed)
    a, p, q = parallax.parallax_offsets(ref, t, rays)
    return a, p, q, rays


@case(parallax.pixels_per_radian, diff=(0, 1, 2, 3))
def _px_per_rad(seed):
    ref, t, rays = _offsets(seed)
    a, p, q = parallax.parallax_offsets(ref, t, rays)
    move = parallax.motion_directions(a, p, q, rays)
    return lens(seed), small_rig(seed).rotations[0], rays, move[0]


@case(parallax.parallax_angle, diff=(0, 1, 2),
      degenerate=[("at infinity", lambda: (jnp.ones(2, F64), jnp.ones(2, F64),
                                           jnp.zeros(2, F64)), False)])
def _parallax_angle(seed):
    return jnp.asarray([0.1, -0.2], F64), jnp.asarray([0.3, 0.2 + seed], F64), \
        jnp.asarray([0.5, 1.5], F64)


@case(spacing.camera_spacing, diff=(0,),
      degenerate=[("two coincident cameras", lambda: (jnp.asarray(
          [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.3, 0.1, 0.0]], F64),), False)])
def _camera_spacing(seed):
    return (small_rig(seed, n=3).translations,)


@case(spacing.spacing_gi_candidates, call=lambda r: spacing.spacing_gi_candidates(r, 5),
      diff=(0,))
def _spacing_gi(seed):
    return (small_rig(seed),)


@case(uniformity.summarize_steps, diff=(0,))
def _summarize(seed):
    return (jnp.asarray([0.3, 0.2 + 0.1 * seed, 0.25], F64),)


@case(uniformity.step_uniformity,
      call=lambda r, c: uniformity.step_uniformity(r, c, pano=PANO, samples=2), diff=(0, 1),
      degenerate=[("no coverage", lambda: (coincident_rig(), candidates(0)), False)])
def _step_uniformity(seed):
    return small_rig(seed), candidates(seed)


# ------------------------------------------------------------------------------ sampling, sweep

@case(bilinear_sample, diff=(0, 1))
def _bilinear(seed):
    return image(seed, 4, 5, 2), jnp.asarray([[1.3, 2.2], [3.6 + 0.1 * seed, 0.4]], F64)


@case(bilinear_sample_zero_padded, diff=(0, 1))
def _bilinear_zero(seed):
    return image(seed, 4, 5, 2), jnp.asarray([[1.3, 2.2], [4.2, -0.3 + 0.1 * seed]], F64)


@case(grid.sweep_points, call=lambda r, c: grid.sweep_points(r, c, PANO), diff=(0, 1))
def _sweep_points(seed):
    return small_rig(seed), candidates(seed)


@case(grid.camera_sweep_grid, call=lambda cam, rot, t, p: grid.camera_sweep_grid(
    cam, rot, t, p, FEATURE_PANO), diff=(0, 1, 2, 3))
def _camera_sweep_grid(seed):
    r = small_rig(seed)
    return lens(seed), r.rotations[0], r.translations[0], grid.sweep_points(r, candidates(seed),
                                                                          PANO)


@case(grid.sweep_grid, call=lambda r, c: grid.sweep_grid(r, c, PANO, FEATURE_PANO),
      diff=(0, 1))
def _sweep_grid(seed):
    return small_rig(seed), candidates(seed)


@case(grid.rescale_pixels, call=lambda c: grid.rescale_pixels(c, (4, 8), (8, 16)), diff=(0,))
def _rescale(seed):
    return (jnp.asarray([[0.5 + seed, 1.0], [3.2, 2.0]], F64),)


@case(grid.feature_to_surrogate,
      call=lambda c: grid.feature_to_surrogate(c, FEATURE_PANO, PANO), diff=(0,))
def _feature_to_surrogate(seed):
    return (jnp.asarray([[0.5 + seed, 1.0], [3.2, 2.0]], F64),)


for _fn in (grid.pixels_from_normalised, grid.normalised_from_pixels):
    case(_fn, call=functools.partial(lambda f, g: f(g, 4, 8), _fn), diff=(0,))(
        lambda seed: (jnp.asarray([[0.5, -0.2 + 0.1 * seed]], F64),))


@case(sample.pad_wrapped, diff=(0,))
def _pad_wrapped(seed):
    return (image(seed, 3, 4, 2),)


@case(sample.sample_wrapped, diff=(0, 1))
def _sample_wrapped(seed):
    return image(seed, 3, 4, 2), jnp.asarray([[3.3, 1.2], [-0.4, 0.7 + 0.1 * seed]], F64)


for _boundary in ("zeros", "wrap"):
    case(sample.sample_map, call=functools.partial(lambda b, m, c: sample.sample_map(m, c, b),
                                                   _boundary),
         diff=(0, 1), label=f"sample_map[{_boundary}]")(
        lambda seed: (image(seed, 3, 4, 2), jnp.asarray([[3.3, 1.2], [-0.4, 0.7 + 0.1 * seed]],
                                                        F64)))


@case(sample.sample_sweep, diff=(0, 1))
def _sample_sweep(seed):
    c = jnp.asarray(np.random.default_rng(seed).uniform(0.2, 2.7, (2, 3, 2, 2)), F64)
    return jnp.stack([image(seed, 3, 4, 2), image(seed + 5, 3, 4, 2)]), c


@case(surrogate.surrogate_grid, call=lambda cam: surrogate.surrogate_grid(cam, PANO), diff=(0,))
def _surrogate_grid(seed):
    return (lens(seed, "ds"),)


@case(surrogate.surrogate_maps, call=lambda r: surrogate.surrogate_maps(r, PANO), diff=(0,))
def _surrogate_maps(seed):
    return (small_rig(seed),)


def _grid_and_image(seed):
    px, ok = surrogate.surrogate_grid(lens(seed), PANO)
    return px, ok, image(seed), image(seed + 3, c=1)[..., 0]


@case(surrogate.resample_surrogate, diff=(0, 2, 3))
def _resample_surrogate(seed):
    return _grid_and_image(seed)


@case(surrogate.resample_surrogates, diff=(0, 2, 3))
def _resample_surrogates(seed):
    a, b = _grid_and_image(seed), _grid_and_image(seed + 7)
    return tuple(jnp.stack([x, y]) for x, y in zip(a, b))


@case(surrogate.surrogate_image, call=lambda cam, im, m: surrogate.surrogate_image(
    cam, im, m, PANO), diff=(0, 1, 2))
def _surrogate_image(seed):
    return lens(seed), image(seed), image(seed + 3, c=1)[..., 0]


@case(surrogate.as_float_image, diff=(0,))
def _as_float_image(seed):
    return (image(seed, 2, 2),)


@case(surrogate.surrogate_images, call=lambda r, im: surrogate.surrogate_images(r, im, pano=PANO),
      diff=(0, 1))
def _surrogate_images(seed):
    return small_rig(seed), jnp.stack([image(seed), image(seed + 1)])


# The network's grids: a 2 x 4 cost panorama into 4 x 8 feature maps, the guide over the 4 x 8
# output panorama into 16 x 32 surrogates.
OUTPUT_PANO = Panorama.hemisphere(4, 8)
SURROGATE_HW = (16, 32)


@case(grids.surrogate_resampling, call=lambda r: grids.surrogate_resampling(r, PANO.shape),
      diff=(0,))
def _surrogate_resampling(seed):
    return (small_rig(seed),)


@case(grids.guide_grids, call=lambda r, c: grids.guide_grids(r, c, OUTPUT_PANO, SURROGATE_HW),
      diff=(0, 1))
def _guide_grids(seed):
    return small_rig(seed), candidates(seed)


@case(grids.sweep_grids, call=lambda r, c: grids.sweep_grids(r, c, PANO, FEATURE_PANO.shape),
      diff=(0, 1),
      degenerate=[("no coverage", lambda: (coincident_rig(), candidates(0)), False)])
def _sweep_grids(seed):
    return small_rig(seed), candidates(seed)


@case(grids.sweep_grids, call=lambda r, c: grids.sweep_grids(
    r, c, PANO, FEATURE_PANO.shape, OUTPUT_PANO, SURROGATE_HW), diff=(0, 1),
      label="sweep_grids[guide]")
def _sweep_grids_guide(seed):
    return small_rig(seed), candidates(seed)


@case(grids.fisheye_surrogates, call=lambda px, ok, im, m: grids.fisheye_surrogates(
    grids.SurrogateMaps(px, ok), im, m), diff=(0, 2, 3))
def _fisheye_surrogates(seed):
    maps = surrogate.surrogate_maps(small_rig(seed), PANO)
    images = jnp.stack([jnp.stack([image(seed + 2 * i), image(seed + 2 * i + 1)])
                        for i in range(2)])
    masks = jnp.stack([jnp.stack([image(seed + 5 + 2 * i, c=1)[..., 0],
                                  image(seed + 6 + 2 * i, c=1)[..., 0]]) for i in range(2)])
    return maps[0], maps[1], images, masks


def _swept(px, ok, cand, features, masks, boundary):
    return grids.sweep_features(features, masks, grids.SweepGrids(px, ok, cand), boundary)


def _sweep_features_args(seed):
    px, ok = grid.sweep_grid(small_rig(seed), candidates(seed), PANO, FEATURE_PANO)
    rng = np.random.default_rng(70 + seed)
    features = jnp.asarray(rng.normal(size=(2, 2, *FEATURE_PANO.shape, 3)), F64)
    # Masks at twice the feature size: their coordinates are rescaled to it.
    masks = jnp.asarray(rng.uniform(-0.5, 1.0, (2, 2, 8, 16)), F64)
    return px, ok, candidates(seed), features, masks


for _boundary in ("zeros", "wrap"):
    case(grids.sweep_features, call=functools.partial(
        lambda b, px, ok, c, f, m: _swept(px, ok, c, f, m, b), _boundary), diff=(0, 3),
         label=f"sweep_features[{_boundary}]")(_sweep_features_args)


@case(grids.sweep_colours, call=lambda px, ok, c, sur, m: grids.sweep_colours(
    sur, m, grids.SweepGrids(px, ok, c, px, ok)), diff=(0, 3, 4))
def _sweep_colours(seed):
    # Grids of the output panorama in surrogate pixels serve as both sweep and guide grids.
    px, ok = grids.guide_grids(small_rig(seed), candidates(seed), OUTPUT_PANO, SURROGATE_HW)
    rng = np.random.default_rng(80 + seed)
    sur = jnp.asarray(rng.uniform(size=(2, 2, *SURROGATE_HW, 3)), F64)
    masks = jnp.asarray(rng.uniform(0.2, 1.0, (2, 2, *SURROGATE_HW)), F64)
    return px, ok, candidates(seed), sur, masks


@case(grids.match_grids, call=lambda r, c: grids.match_grids(r, c, PANO, SURROGATE_HW, 2),
      diff=(0, 1))
def _match_grids(seed):
    return small_rig(seed), candidates(seed)


@case(grids.sweep_grids, call=lambda r, c: grids.sweep_grids(
    r, c, PANO, FEATURE_PANO.shape, None, SURROGATE_HW, match_samples=2), diff=(0, 1),
      label="sweep_grids[match]")
def _sweep_grids_match(seed):
    return small_rig(seed), candidates(seed)


@case(grids.match_grey, call=lambda px, ok, c, sur, m: grids.match_grey(
    sur, m, grids.SweepGrids(px, ok, c, match_px=px, match_ok=ok)), diff=(0, 3, 4))
def _match_grey(seed):
    px, ok = grids.match_grids(small_rig(seed), candidates(seed), PANO, SURROGATE_HW, 2)
    rng = np.random.default_rng(90 + seed)
    sur = jnp.asarray(rng.uniform(size=(2, 2, *SURROGATE_HW, 3)), F64)
    masks = jnp.asarray(rng.uniform(0.2, 1.0, (2, 2, *SURROGATE_HW)), F64)
    return px, ok, candidates(seed), sur, masks


@case(matching.cell_zncc, call=lambda g, s: matching.cell_zncc(g, s, 2), diff=(0,),
      degenerate=[("flat patches", lambda: (jnp.full((1, 3, 2, 4, 4), 0.5, F64),
                                            jnp.ones((1, 3, 2, 4, 4), F64)), False)])
def _cell_zncc(seed):
    rng = np.random.default_rng(95 + seed)
    grey = jnp.asarray(rng.uniform(size=(2, 3, 2, 4, 6)), F64)
    seen = jnp.asarray((rng.uniform(size=(2, 3, 2, 4, 6)) > 0.1).astype(np.float64))
    return grey, seen


@case(matching.cell_zncc_batch_last,
      call=lambda g, s: matching.cell_zncc_batch_last(g, s, 2), diff=(0,),
      degenerate=[("flat patches", lambda: (jnp.full((3, 2, 4, 4, 1), 0.5, F64),
                                            jnp.ones((3, 2, 4, 4, 1), F64)), False)])
def _cell_zncc_batch_last(seed):
    grey, seen = _cell_zncc(seed)
    return jnp.moveaxis(grey, 0, -1), jnp.moveaxis(seen, 0, -1)


@case(consistency.common_mean_gains, diff=(0,))
def _common_mean_gains(seed):
    return (jnp.asarray(np.random.default_rng(seed).uniform(0.1, 0.9, (2, 3, 3)), F64),)


@case(consistency.view_dispersion, diff=(0, 1),
      degenerate=[("no camera sees", lambda: (jnp.ones((2, 3, 3), F64), jnp.zeros((2, 3), F64)),
                   False)])
def _view_dispersion(seed):
    w = jnp.asarray(np.random.default_rng(seed).uniform(0.2, 1.0, (3, 4)), F64)
    return jnp.stack([image(seed, 4, 1)[:, 0], image(seed + 1, 4, 1)[:, 0],
                      image(seed + 2, 4, 1)[:, 0]]), w


# ------------------------------------------------------------------------------ calibrate

CALIB_PANO = Panorama.hemisphere(2, 4)


def _calib_params(seed, intrinsics=True):
    rng = np.random.default_rng(40 + seed)
    p = calib_refine.initial_parameters(small_rig(seed), np.full((1, 2, 4), -0.5), intrinsics)
    return {k: jnp.asarray(np.asarray(v) + 0.01 * rng.normal(size=v.shape), F64)
            for k, v in p.items()}


def _calib_frame(seed):
    ims = jnp.stack([image(seed), image(seed + 1)])
    return ims, jnp.ones(ims.shape[:3], F64)


@case(calib_refine.initial_parameters, call=lambda r, li: calib_refine.initial_parameters(
    r, li, True), diff=(1,))
def _calib_initial(seed):
    return small_rig(seed), jnp.full((1, 2, 4), -0.5 + 0.1 * seed, F64)


@case(calib_refine.apply_calibration, diff=(0, 1))
def _calib_apply(seed):
    return small_rig(seed), _calib_params(seed)


@case(calib_refine.prepare_images,
      call=lambda im, m: calib_refine.prepare_images(im, m, 0.8, 2, 1.2, 2),
      diff=(0,))
def _calib_prepare(seed):
    return _calib_frame(seed)


@case(calib_refine.frame_terms, call=lambda r, im, m, li: calib_refine.frame_terms(
    r, im, m, li, CALIB_PANO), diff=(0, 1, 3))
def _calib_frame_terms(seed):
    return (small_rig(seed), *_calib_frame(seed), _calib_params(seed)["log_inv"][0])


@case(calib_refine.frame_samples, call=lambda r, im, m, li: calib_refine.frame_samples(
    r, im, m, li, CALIB_PANO), diff=(0, 1, 3))
def _calib_frame_samples(seed):
    return (small_rig(seed), *_calib_frame(seed), _calib_params(seed)["log_inv"][0])


@case(calib_refine.refinement_loss, call=lambda p, r, im, m: calib_refine.refinement_loss(
    p, r, im, m, CALIB_PANO), diff=(0,))
def _calib_loss(seed):
    ims, ms = _calib_frame(seed)
    return _calib_params(seed), small_rig(seed), ims[None], ms[None]


# ---------------------------------------------------------------- label-free objective

# Two cameras' 4 x 8 hemisphere surrogates of one sample; the panorama is PANO (2 x 4).
LF_SPANO = Panorama.hemisphere(4, 8)


def _lf_batch(seed):
    sur = jnp.stack([image(seed, 4, 8), image(seed + 1, 4, 8)])[None]      # (1, 2, 4, 8, 3)
    masks = jnp.asarray(np.random.default_rng(60 + seed).uniform(0.6, 1.0, (1, 2, 4, 8)), F64)
    return sur, masks


def _lf_inv(seed):
    return jnp.asarray(np.random.default_rng(70 + seed).uniform(0.3, 1.5, (1, *PANO.shape)), F64)


@case(unlabeled.normalize_gain, diff=(0,))
def _lf_normalize_gain(seed):
    return _lf_batch(seed)


@case(unlabeled.camera_samples, call=lambda sur, m, r, inv: unlabeled.camera_samples(
    sur, m, r, inv, PANO, LF_SPANO), diff=(0, 1, 2, 3))
def _lf_camera_samples(seed):
    return (*_lf_batch(seed), small_rig(seed), _lf_inv(seed))


@case(unlabeled.camera_samples, label="camera_samples[occlusion]",
      call=lambda sur, m, r, inv: unlabeled.camera_samples(sur, m, r, inv, PANO, LF_SPANO,
                                                           occlusion=0.05), diff=(0, 1, 3))
def _lf_camera_samples_occlusion(seed):
    return (*_lf_batch(seed), small_rig(seed), _lf_inv(seed))


@case(unlabeled.photometric_map, call=lambda sur, m, r, inv: unlabeled.photometric_map(
    sur, m, r, inv, PANO, LF_SPANO), diff=(0, 3))
def _lf_photometric_map(seed):
    return (*_lf_batch(seed), small_rig(seed), _lf_inv(seed))


@case(unlabeled.photometric_loss, call=lambda sur, m, r, inv: unlabeled.photometric_loss(
    sur, m, r, inv, PANO, LF_SPANO), diff=(0, 2, 3))
def _lf_photometric_loss(seed):
    return (*_lf_batch(seed), small_rig(seed), _lf_inv(seed))


@case(unlabeled.reference_colours, call=lambda sur, m, r, inv: unlabeled.reference_colours(
    sur, m, r, inv, PANO, LF_SPANO), diff=(0, 1, 3))
def _lf_reference_colours(seed):
    return (*_lf_batch(seed), small_rig(seed), _lf_inv(seed))


# The colours (edge weights) and the teacher's map are targets, held constant (stop_gradient):
# only the prediction is differentiated.
@case(unlabeled.edge_aware_smoothness, diff=(0,))
def _lf_smoothness(seed):
    return _lf_inv(seed), jnp.broadcast_to(image(seed, *PANO.shape), (1, *PANO.shape, 3))


@case(unlabeled.teacher_loss, diff=(0,))
def _lf_teacher_loss(seed):
    mask = jnp.asarray(np.random.default_rng(80 + seed).uniform(size=(1, *PANO.shape)) > 0.3,
                       F64)
    return _lf_inv(seed), _lf_inv(seed + 5), mask


@case(unlabeled.teacher_confidence, call=lambda sur, m, r, t, v: unlabeled.teacher_confidence(
    sur, m, r, t, v, PANO, LF_SPANO, 0.2))
def _lf_teacher_confidence(seed):
    valid = jnp.asarray(np.random.default_rng(90 + seed).uniform(size=(1, *PANO.shape)) > 0.2)
    return (*_lf_batch(seed), small_rig(seed), _lf_inv(seed), valid)


def _lf_terms(seed):
    sur, masks = _lf_batch(seed)
    return _lf_inv(seed), {"surrogates": sur, "masks": masks, "teacher_inv": _lf_inv(seed + 3),
                           "teacher_mask": jnp.ones((1, *PANO.shape), F64)}, small_rig(seed)


case(unlabeled.label_free_terms, call=lambda inv, b, r: unlabeled.label_free_terms(
    unlabeled.LabelFree(smoothness=0.0, teacher=0.1), inv, b, r, PANO), diff=(0,))(_lf_terms)
# The smoothness term's edge weights come from the cameras' colours at the predicted points,
# held constant: its gradient leaves out how they move with the prediction, which central
# differences see. Transformations only.
case(unlabeled.label_free_terms, label="label_free_terms[smoothness]",
     call=lambda inv, b, r: unlabeled.label_free_terms(
         unlabeled.LabelFree(smoothness=0.5, teacher=0.1), inv, b, r, PANO))(_lf_terms)


# ------------------------------------------------------------------------------ baseline

_view_image_jit = jax.jit(lambda c, im, m: views.view_image(VIEW, c, im, m))


@functools.lru_cache(maxsize=None)
def _view_masks(seed):
    r = small_rig(seed)
    return r, [_view_image_jit(c, image(seed), jnp.ones((SIZE, SIZE), F64))[1] for c in r.cameras]


@case(camera_select.camera_at, call=lambda r: camera_select.camera_at(r, 1), diff=(0,))
def _camera_at(seed):
    return (small_rig(seed),)


@case(camera_select.item_at, call=lambda a, b: camera_select.item_at([a, b], 1), diff=(0, 1))
def _item_at(seed):
    return image(seed, 2, 2), image(seed + 1, 2, 2)


@case(camera_select.reference_rays, call=lambda r, m: camera_select.reference_rays(
    r, VIEW, 0, m), diff=(0,))
def _reference_rays(seed):
    r, masks = _view_masks(seed)
    return r, masks[0]


@case(camera_select.points_at, call=lambda r, rays, d: camera_select.points_at(r, 0, rays, d),
      diff=(0, 1, 2))
def _points_at(seed):
    return small_rig(seed), numerics.unit(points(seed, 4)).reshape(2, 2, 3), candidates(seed)


@case(camera_select.project_into_view, call=lambda r, m, p: camera_select.project_into_view(
    r, VIEW, 1, m, p), diff=(0, 2))
def _project_into_view(seed):
    r, masks = _view_masks(seed)
    return r, masks[1], points(seed)


@case(camera_select.for_each_camera, call=lambda r, masks: camera_select.for_each_camera(
    r, masks, lambda j, acc: acc + jnp.sum(camera_select.item_at(masks, j)) * (j + 1), 0.0),
      diff=(1,))
def _for_each_camera(seed):
    r, masks = _view_masks(seed)
    return r, masks


@case(camera_select.select_best_camera, call=lambda r, c, masks: camera_select.select_best_camera(
    r, VIEW, 0, c, masks), diff=(0, 1))
def _select(seed):
    r, masks = _view_masks(seed)
    return r, candidates(seed), masks


@case(camera_select.sweep_coords, call=lambda r, c, best, masks: camera_select.sweep_coords(
    r, VIEW, 0, c, best, masks), diff=(0, 1))
def _sweep_coords(seed):
    r, masks = _view_masks(seed)
    best = jax.jit(lambda r, c, m: camera_select.select_best_camera(r, VIEW, 0, c, m)["best"])(
        r, candidates(seed), masks)
    return r, candidates(seed), best, masks


@case(cost_filter.edge_aware_filter,
      call=lambda c, w, g: cost_filter.edge_aware_filter(c, w, g, levels=2), diff=(0, 1, 2),
      degenerate=[("no confidence", lambda: (jnp.ones((2, 4, 4), F64), jnp.zeros((4, 4), F64),
                                             image(0, 4, 4)), False)])
def _edge_aware(seed):
    return jnp.moveaxis(image(seed, 4, 4, 2), -1, 0), image(seed + 1, 4, 4, 1)[..., 0], \
        image(seed + 2, 4, 4)


def _cost_inputs(seed):
    ref = image(seed, 5, 5)
    warped = jnp.stack([image(seed + 1, 5, 5), ref + 0.01])
    ok = jnp.asarray(np.random.default_rng(seed).uniform(size=(2, 5, 5)) > 0.2)
    return ref, warped, ok


@case(matching_cost.ad_cost, call=lambda r, w, ok: matching_cost.ad_cost(r, w, ok, 0.5),
      diff=(0, 1))
def _ad(seed):
    return _cost_inputs(seed)


@case(matching_cost.box_sum, call=lambda x: matching_cost.box_sum(x, 3), diff=(0,))
def _box_sum(seed):
    return (image(seed, 4, 5, 2),)


@case(matching_cost.zncc_cost, call=lambda r, w, ok: matching_cost.zncc_cost(r, w, ok, 0.5, 3),
      diff=(0, 1), fd_tol=1e-4,
      degenerate=[("flat patches", lambda: (jnp.ones((5, 5, 3), F64), jnp.ones((2, 5, 5, 3), F64),
                                            jnp.ones((2, 5, 5), bool)), False)])
def _zncc(seed):
    return _cost_inputs(seed)


@case(matching_cost.matching_cost,
      call=lambda r, w, ok: matching_cost.matching_cost("zncc", r, w, ok, 0.5, 3), diff=(0, 1),
      fd_tol=1e-4)
def _matching_cost(seed):
    return _cost_inputs(seed)


@functools.lru_cache(maxsize=None)
def _rtss_inputs(seed):
    r = small_rig(seed)
    ims = jnp.stack([image(seed), image(seed + 1)])
    # float32 masks, as rtss_predict passes them on: both entries share sphere_sweep's program.
    return r, ims, jnp.ones((2, SIZE, SIZE), jnp.float32), candidates(seed)


@case(rtss.preset_candidates, call=lambda r: rtss.preset_candidates(
    r, RTSS_CONFIG.replace(candidates="gi")), diff=(0,), fd_tol=1e-3)
def _preset_candidates(seed):
    return (small_rig(seed),)


# The sphere sweep is a winner-take-all: its outputs are piecewise constant in everything but
# the parabola refinement, so its gradients are not compared with finite differences here.
@case(rtss.sphere_sweep, call=lambda r, im, m, c: rtss.sphere_sweep(r, im, m, c, PANO,
                                                                      RTSS_CONFIG),
      rtol=1e-5, atol=1e-6)
def _sphere_sweep(seed):
    return _rtss_inputs(seed)


@case(rtss.rtss_predict, call=lambda r, im, m, c: rtss.rtss_predict(r, im, m, c, PANO,
                                                                      RTSS_CONFIG),
      rtol=1e-5, atol=1e-6)
def _rtss_predict(seed):
    return _rtss_inputs(seed)


def _reference_inputs(seed):
    r, ims, masks, c = _rtss_inputs(seed)
    vs = [_view_image_jit(cam, im, m) for cam, im, m in zip(r.cameras, ims, masks)]
    return r, [v[0] for v in vs], [v[1] for v in vs], c


@case(rtss.reference_map, call=lambda r, ims, masks, c: rtss.reference_map(
    r, VIEW, 0, ims, masks, [m.shape for m in masks], c, RTSS_CONFIG), rtol=1e-5, atol=1e-6)
def _reference_map(seed):
    return _reference_inputs(seed)


@functools.lru_cache(maxsize=None)
def _maps(seed):
    rng = np.random.default_rng(seed)
    inv = jnp.asarray(rng.uniform(0.2, 1.5, (2, 8, 8)), F64)
    valid = jnp.asarray(rng.uniform(size=(2, 8, 8)) > 0.3)
    weight = jnp.asarray(rng.uniform(1.0, 3.0, (2, 8, 8)), F64)
    return inv, valid, weight


@case(stitch.pair_visibility, call=lambda r, m, c: stitch.pair_visibility(r, m, c, PANO))
def _pair_visibility(seed):
    r, _, masks, c = _rtss_inputs(seed)
    return r, masks, c


@case(stitch.resample_to_panorama, call=lambda r, inv, val, w: stitch.resample_to_panorama(
    r, VIEW, (0, 1), inv, val, w, PANO, jnp.linspace(2.0, 0.01, 4), 0.1), diff=(1, 3),
      rtol=1e-6, atol=1e-8)
def _resample_to_panorama(seed):
    return (small_rig(seed), *_maps(seed))


@case(stitch.fill_holes, call=lambda inv, val, allowed: stitch.fill_holes(inv, val, allowed, 2),
      diff=(0,))
def _fill_holes(seed):
    inv, valid, _ = _maps(seed)
    return inv[0], valid[0], jnp.ones((8, 8), bool)


@case(stitch.blend_estimates, call=lambda inv, val, w: stitch.blend_estimates(inv, val, w, 0.05),
      diff=(0, 2), degenerate=[("nothing valid", lambda: (jnp.ones((2, 8, 8), F64),
                                                          jnp.zeros((2, 8, 8), bool),
                                                          jnp.ones((2, 8, 8), F64)), False)])
def _blend(seed):
    return _maps(seed)


@case(stitch.stitch, call=lambda r, inv, val, w, m, c: stitch.stitch(
    r, VIEW, (0, 1), inv, val, w, m, c, PANO, 4, 1), diff=(1, 3), rtol=1e-6, atol=1e-8)
def _stitch(seed):
    r, _, masks, c = _rtss_inputs(seed)
    return (r, *_maps(seed), masks, c)


@case(views.view_camera, call=lambda c: views.view_camera(VIEW, c), diff=(0,))
def _view_camera(seed):
    return (lens(seed),)


for _kind in ("fisheye", "equirect"):
    _view = views.MatchView(_kind, 8)
    case(views.view_rays, call=functools.partial(views.view_rays, _view), diff=(0,),
         label=f"view_rays[{_kind}]")(lambda seed: (lens(seed, "ds"),))
    case(views.view_pixels, call=functools.partial(views.view_pixels, _view), diff=(0, 1),
         label=f"view_pixels[{_kind}]",
         degenerate=[("axis, edge, behind, centre",
                      lambda: (lens(0, "ds"), degenerate_points()), False)])(
        lambda seed: (lens(seed, "ds"), points(seed)))


@case(views.view_image, call=lambda c, im, m: views.view_image(VIEW, c, im, m), diff=(0, 1, 2))
def _view_image(seed):
    return lens(seed), image(seed), image(seed + 1, c=1)[..., 0]


@case(views.sample_mask_nearest, diff=(1,))
def _sample_mask_nearest(seed):
    return image(seed, 4, 4, 1)[..., 0], jnp.asarray([[1.2, 2.3 + 0.1 * seed]], F64), \
        jnp.asarray([True])


@case(winner.parabola_offset, diff=(0, 1, 2),
      degenerate=[("flat", lambda: (jnp.ones(2, F64), jnp.ones(2, F64), jnp.ones(2, F64)),
                   False)])
def _parabola(seed):
    return jnp.asarray([0.5, 0.9], F64), jnp.asarray([0.2, 0.3 + 0.05 * seed], F64), \
        jnp.asarray([0.45, 0.6], F64)


@case(winner.index_to_inverse_distance, diff=(0, 1))
def _index_to_inverse(seed):
    return jnp.asarray([0.3, 1.7 + 0.1 * seed], F64), candidates(seed)


@case(winner.winner_take_all, diff=(0, 1))
def _wta(seed):
    return jnp.moveaxis(image(seed, 3, 3, 4), -1, 0), candidates(seed)


# ------------------------------------------------------------------------------ design

COINCIDENT_LAYOUT = [("coincident cameras", lambda: (design_spec.make_layout(
    np.zeros((3, 2)), dtype=F64),), False)]


@case(design_spec.make_layout, diff=(0, 1, 2))
def _make_layout(seed):
    lay = layout(seed)
    return lay.positions, lay.heights, lay.rotvecs


for _fn in (objective.free_layout, objective.layout_pose, constraints.violations,
            constraints.penalty, constraints.project, constraints.is_feasible):
    case(_fn, call=functools.partial(lambda f, lay: f(lay, SPEC), _fn), diff=(0,),
         degenerate=COINCIDENT_LAYOUT)(lambda seed: (layout(seed),))


@case(objective.occluder_margin, call=lambda o, t: objective.occluder_margin(SPEC, o, t),
      diff=(0, 1), degenerate=[("zero-length and vertical segments", lambda: (
          jnp.asarray([[0.1, 0.0, 0.05], [0.2, 0.0, -0.1], [0.0, 0.0, 0.02]], F64),
          jnp.asarray([[0.1, 0.0, 0.05], [0.2, 0.0, 1.0], [0.0, 0.0, 3.0]], F64)), False)])
def _occluder_margin(seed):
    rng = np.random.default_rng(seed)
    return jnp.asarray(rng.normal(size=(3, 3)) * 0.3 + [0, 0, 0.05], F64), \
        jnp.asarray(rng.normal(size=(3, 3)) + [0, 0, 1.0], F64)


@case(objective.at_least_two, diff=(0,))
def _at_least_two(seed):
    return (jnp.asarray(np.random.default_rng(seed).uniform(0.1, 0.9, (3, 4)), F64),)


for _fn in (objective.objective_terms, objective.objective, objective.camera_counts,
            optimize.total_loss):
    case(_fn, call=functools.partial(lambda f, lay: f(lay, SPEC), _fn),
         diff=() if _fn is objective.camera_counts else (0,),
         degenerate=COINCIDENT_LAYOUT, fd_tol=1e-4)(lambda seed: (layout(seed),))


@case(optimize.batch_report, call=lambda lays: optimize.batch_report(lays, SPEC), diff=(0,),
      fd_tol=1e-4)
def _batch_report(seed):
    return (optimize.stack_layouts([layout(seed), layout(seed + 2)]),)


@case(optimize.stack_layouts, call=lambda a, b: optimize.stack_layouts([a, b]), diff=(0, 1))
def _stack(seed):
    return layout(seed), layout(seed + 1)


@case(optimize.index_layout, call=lambda lays: optimize.index_layout(lays, 1), diff=(0,))
def _index(seed):
    return (optimize.stack_layouts([layout(seed), layout(seed + 1)]),)


@case(optimize.random_layouts,
      call=lambda key: optimize.random_layouts(key, SPEC, 2, dtype=F64))
def _random_layouts(seed):
    return (jax.random.PRNGKey(seed),)


# ------------------------------------------------------------------------------ augmentation

# Keyed entries: seed 1 differs from seed 0 in the key alone, so that different outputs are the
# key's doing. Rounding to 8 bits (JPEG) may move a value by one level between compiled and
# op-by-op arithmetic, hence the tolerance of one level there.
ONE_LEVEL = 1.01 / 255.0
AUGMENT_ALL = augment.AugmentConfig(p_vignetting=1.0, p_blur=1.0, p_colour=1.0, p_noise=1.0,
                                    p_jpeg=1.0, p_body=1.0)


def key(seed):
    return jax.random.PRNGKey(seed)


@case(photometric.noise_variance, diff=(0, 1, 2))
def _noise_variance(seed):
    return image(seed, 4, 4), jnp.asarray(1e-3 * (1 + seed), F64), jnp.asarray(0.004, F64)


@case(photometric.sensor_noise, call=lambda k, im: photometric.sensor_noise(k, im, 2e-3, 0.01),
      keys=(0,))
def _sensor_noise(seed):
    return key(seed), image(0, 4, 4)


@case(photometric.gaussian_kernel, call=lambda s: photometric.gaussian_kernel(s, 2))
def _gaussian_kernel(seed):
    return (jnp.asarray(0.7 + 0.2 * seed, F64),)


@case(photometric.gaussian_blur, call=lambda im, s: photometric.gaussian_blur(im, s, 2))
def _gaussian_blur(seed):
    return image(seed, 6, 6), jnp.asarray(0.8 + 0.3 * seed, F64)


@case(photometric.exposure_white_balance, diff=(0, 1, 2, 3))
def _exposure_white_balance(seed):
    # Inside the clip (image * exposure * gains < 1), where the function is smooth.
    return (image(seed, 4, 4) * 0.6, jnp.asarray(1.2 - 0.1 * seed, F64),
            jnp.asarray([1.1, 1.0, 0.9 + 0.05 * seed], F64), jnp.asarray(0.9 + 0.2 * seed, F64))


@case(photometric.vignetting_factor,
      call=lambda c, r, s: photometric.vignetting_factor(6, 8, c, r, s))
def _vignetting_factor(seed):
    return jnp.asarray([3.5 + seed, 2.5], F64), jnp.asarray(3.0, F64), jnp.asarray(0.4, F64)


@case(photometric.vignetting)
def _vignetting(seed):
    return image(seed, 6, 8), jnp.asarray([3.5, 2.5 + seed], F64), jnp.asarray(3.0, F64), \
        jnp.asarray(0.5, F64)


@case(photometric.quality_table, call=lambda q: photometric.quality_table(
    photometric.LUMA_TABLE, q))
def _quality_table(seed):
    return (jnp.asarray([30.0, 75.0][seed], F64),)


@case(photometric.block_dct_quantise, atol=1e-4)
def _block_dct_quantise(seed):
    plane = np.random.default_rng(seed).uniform(-128, 127, (8, 16))
    return jnp.asarray(plane, F64), photometric.quality_table(photometric.CHROMA_TABLE, 60.0)


@case(photometric.jpeg_compress, atol=ONE_LEVEL)
def _jpeg_compress(seed):
    return image(seed, 8, 8), jnp.asarray(50.0 + 20 * seed, F64)


@case(augment.augment_sample, call=lambda k, im, m: augment.augment_sample(k, im, m,
                                                                           AUGMENT_ALL),
      keys=(0,), atol=ONE_LEVEL)
def _augment_sample(seed):
    # One camera: the cameras are a Python loop, each one more copy of every stage to compile.
    return key(seed), image(0, 8, 8)[None], jnp.ones((1, 8, 8), F64)


# ------------------------------------------------------------------------------ render

RENDER_PANO = Panorama.hemisphere(2, 4)


@functools.lru_cache(maxsize=None)
def _scene(seed):
    """A sphere over the ground plane, the sphere moved by the seed."""
    sphere = sphere_scene(jnp.asarray([1.5 + 0.2 * seed, 0.3, 0.4]), 0.5)
    return sphere.replace(plane_height=plane_scene(-1.2).plane_height)


@case(render_scene.is_indoor, call=lambda k: render_scene.is_indoor(k, "mixed"), keys=(0,))
def _is_indoor(seed):
    return (key((0, 3)[seed]),)       # one room, one outdoor scene


@case(render_scene.primitive_distances)
def _primitive_distances(seed):
    return (_scene(seed),)


@case(render_scene.textured_sphere, keys=(2,), rtol=1e-5)   # float32 materials
def _textured_sphere(seed):
    return jnp.asarray([1.0, 0.5, 0.2]), jnp.asarray(0.7), key(seed)


@case(render_views.sample_keys, keys=(0,))
def _sample_keys(seed):
    return (key(seed),)


@case(render_views.trace_distance)
def _trace_distance(seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(6, 3))
    return (_scene(seed), jnp.zeros((6, 3), jnp.float32),
            jnp.asarray(d / np.linalg.norm(d, axis=1, keepdims=True), jnp.float32))


@case(render_views.camera_rays)
def _camera_rays(seed):
    return lens(seed), jnp.asarray(rotations.axis_angle_to_matrix(jnp.asarray([0.1 * seed, 0.2, 0.0],
                                                                          F64))), \
        jnp.asarray([0.1, 0.0, 0.05 * seed], F64)


@case(render_views.render_panorama_distance,
      call=lambda sc, ref: render_views.render_panorama_distance(sc, ref, RENDER_PANO, chunk=8))
def _render_panorama_distance(seed):
    return _scene(seed), jnp.asarray([0.0, 0.1 * seed, 0.0], jnp.float32)


# ------------------------------------------------------------------------------ losses, metrics

@functools.lru_cache(maxsize=None)
def _labels(seed, b=1, h=12, w=12):
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.3, 150.0, (b, h, w))
    d[0, 0, :3] = [1e6, np.inf, -1.0]  # sky, non-finite, negative
    valid = rng.uniform(size=(b, h, w)) > 0.1
    inv = 1.0 / np.clip(d, 0.5, 100.0) + rng.normal(size=d.shape) * 0.05
    return jnp.asarray(inv, F64), jnp.asarray(d, F64), jnp.asarray(valid), candidates(0, 5)


@functools.lru_cache(maxsize=None)
def _prob(seed, b=1, h=12, w=12):
    logits = np.random.default_rng(seed).normal(size=(b, 5, h, w))
    return jax.nn.softmax(jnp.asarray(logits, F64), axis=1)


@case(labels.usable_label)
def _usable_label(seed):
    _, d, _, _ = _labels(seed)
    return (d,)


@case(labels.label_mask)
def _label_mask(seed):
    _, d, valid, _ = _labels(seed)
    return d, valid


@case(labels.clamped_inverse, diff=(0, 1))
def _clamped_inverse(seed):
    _, d, _, c = _labels(seed)
    return d, c


@case(losses.two_hot_target, diff=(0, 1))
def _two_hot(seed):
    _, d, _, c = _labels(seed)
    return d, c


@case(losses.volume_loss, diff=(0, 3),
      degenerate=[("saturated probabilities", lambda: (
          jax.nn.one_hot(jnp.zeros((1, 12, 12), int), 5, axis=1, dtype=F64),
          *_labels(0)[1:]), False)])
def _volume_loss(seed):
    _, d, valid, c = _labels(seed)
    return _prob(seed), d, valid, c


@case(losses.smooth_l1, diff=(0,), degenerate=[("zero", lambda: (jnp.zeros(3, F64),), False)])
def _smooth_l1(seed):
    return (jnp.asarray([0.3, -2.0, 1.5 + seed], F64),)


@case(losses.smooth_l1_loss, diff=(0, 3))
def _smooth_l1_loss(seed):
    return _labels(seed)


@case(losses.model_loss, call=lambda p, d, v, c: losses.model_loss(
    "volume", {"prob": p}, d, v, c), diff=(0, 3))
def _model_loss(seed):
    _, d, valid, c = _labels(seed)
    return _prob(seed), d, valid, c


for _fn in (metrics.ssim_map, metrics.paper_ssim):
    case(_fn, diff=(0, 1), fd_tol=1e-4)(lambda seed: (_labels(seed)[0], _labels(seed + 5)[0]))

for _fn in (metrics.inverse_errors, metrics.paper_sample_metrics, metrics.gijax_batch_sums):
    case(_fn, diff=(0,), fd_tol=1e-4,
         degenerate=[("perfect prediction", lambda: (
             labels.clamped_inverse(*_labels(0)[1:4:2]), *_labels(0)[1:]), False)])(_labels)


@case(metrics.paper_label_mask)
def _paper_label_mask(seed):
    return _labels(seed)[1:]


for _set in ("paper", "gijax"):
    case(metrics.batch_sums, call=functools.partial(
        lambda s, p, d, v, c: metrics.batch_sums(p, d, v, c, metric_set=s), _set), diff=(0,),
         fd_tol=1e-4, label=f"batch_sums[{_set}]")(_labels)


# ------------------------------------------------------------------------------ network functions

@case(cost_volume.masked_variance, diff=(0,),
      degenerate=[("no camera valid", lambda: (_features(0), jnp.zeros((1, 3, 2, 3, 4))), False),
                  ("one camera valid", lambda: (
                      _features(0), jnp.zeros((1, 3, 2, 3, 4)).at[:, 0].set(1.0)), False)])
def _masked_variance(seed):
    valid = np.random.default_rng(seed + 7).uniform(size=(1, 3, 2, 3, 4)) > 0.3
    return _features(seed), jnp.asarray(valid, F64)


def _features(seed):
    return jnp.asarray(np.random.default_rng(seed).normal(size=(1, 3, 2, 3, 4, 2)), F64)


@case(layers.leaky_relu, diff=(0,))
def _leaky_relu(seed):
    # Away from 0, where the derivative jumps.
    x = np.random.default_rng(seed).normal(size=7)
    return (jnp.asarray(np.where(np.abs(x) < 0.05, 0.5, x), F64),)


@case(layers.tap_sum_2d, diff=(0,))
def _tap_sum_2d(seed):
    return (jnp.asarray(np.random.default_rng(seed).normal(size=(2, 4, 5, 9)), F64),)


@case(layers.kernel_init, call=lambda k: layers.kernel_init(k, (3, 3, 2, 4), F64))
def _kernel_init(seed):
    return (jax.random.key_data(jax.random.key(seed)),)


@case(regressor.regress, call=lambda logits, c: regressor.regress(logits, c, (4, 6)),
      diff=(0, 1),
      degenerate=[("one-hot logits", lambda: (
          jnp.asarray(np.eye(4)[[0, 3, 1]].T.reshape(1, 4, 1, 3).repeat(2, 2) * 60.0, F64),
          candidates(0)), False)])
def _regress(seed):
    logits = np.random.default_rng(seed).normal(size=(1, 4, 2, 3))
    return jnp.asarray(logits, F64), candidates(seed)


def _probabilities(seed, shape=(1, 6, 2, 3)):
    logits = np.random.default_rng(seed).normal(size=shape) * 2.0
    e = np.exp(logits - logits.max(1, keepdims=True))
    return jnp.asarray(e / e.sum(1, keepdims=True), F64)


@case(regressor.estimate_inverse,
      call=lambda prob, inv: regressor.estimate_inverse(prob, inv, "mode", 1), diff=(0, 1),
      degenerate=[("a tie and a one-hot pixel", lambda: (
          jnp.asarray(np.stack([np.eye(6)[[1, 4]].sum(0) / 2, np.eye(6)[5]], -1)
                      .reshape(1, 6, 1, 2), F64),
          jnp.asarray(np.linspace(2.0, 0.01, 6), F64)), False)])
def _estimate_inverse(seed):
    return _probabilities(seed), 1.0 / candidates(seed, 6)


@case(regressor.estimate_inverse, label="estimate_inverse[pick]",
      call=lambda prob, inv: regressor.estimate_inverse(prob, inv, "mode", 2, 1), diff=(0, 1))
def _estimate_inverse_pick(seed):
    return _probabilities(seed), 1.0 / candidates(seed, 6)


@case(regressor.mode_window_mask, call=lambda prob: regressor.mode_window_mask(prob, 2))
def _mode_window_mask(seed):
    return (_probabilities(seed),)


@case(refine.colour_guide, diff=(0, 2))
def _colour_guide(seed):
    rng = np.random.default_rng(seed)
    colour = rng.uniform(size=(1, 3, 4, 2, 3, 3))
    seen = np.ones((1, 3, 4, 2, 3))
    seen[:, 2, ::2] = 0.0                 # a camera that misses every other candidate
    prob = rng.dirichlet(np.ones(4), size=(1, 2, 3)).transpose(0, 3, 1, 2)
    return jnp.asarray(colour, F64), jnp.asarray(seen, F64), jnp.asarray(prob, F64)


def _taps_tables():
    offsets = spherical.tangent_offsets(4, 8)
    index, weight = spherical.sampling_tables(offsets, 8)
    return jnp.asarray(index), jnp.asarray(weight, F64)


@case(spherical.gather_taps, call=lambda x, w: spherical.gather_taps(x, _taps_tables()[0], w),
      diff=(0, 1))
def _gather_taps(seed):
    x = np.random.default_rng(seed).normal(size=(1, 4, 8, 2))
    return jnp.asarray(x, F64), _taps_tables()[1]


@case(spherical.mix_taps_one_by_one,
      call=lambda x, w, k: spherical.mix_taps_one_by_one(x, _taps_tables()[0], w, k),
      diff=(0, 1, 2))
def _mix_taps_one_by_one(seed):
    rng = np.random.default_rng(seed)
    x, kernel = rng.normal(size=(1, 4, 8, 2)), rng.normal(size=(9 * 2, 3))
    return jnp.asarray(x, F64), _taps_tables()[1], jnp.asarray(kernel, F64)


@case(upsample.upsample2_axis, call=lambda x: upsample.upsample2_axis(x, 1), diff=(0,))
def _upsample2_axis(seed):
    return (jnp.asarray(np.random.default_rng(seed).normal(size=(1, 3, 4)), F64),)


@case(upsample.upsample2, call=lambda x: upsample.upsample2(x, (1, 2)), diff=(0,))
def _upsample2(seed):
    return (jnp.asarray(np.random.default_rng(seed).normal(size=(1, 3, 4, 2)), F64),)


# ------------------------------------------------------------------------------ generic tests

def _float_leaves(tree):
    return [x for x in jax.tree_util.tree_leaves(tree)
            if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)]


def _assert_trees_close(a, b, rtol, atol, what):
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(la) == len(lb), what
    for x, y in zip(la, lb):
        x, y = np.asarray(x), np.asarray(y)
        assert x.shape == y.shape and x.dtype == y.dtype, (what, x.shape, y.shape)
        if np.issubdtype(x.dtype, np.floating):
            np.testing.assert_allclose(x, y, rtol=rtol, atol=atol, equal_nan=True, err_msg=what)
        else:
            np.testing.assert_array_equal(x, y, err_msg=what)


def _weighted(out):
    """A fixed random weighting of every finite floating output: the scalar whose gradient is
    tested. NaN outputs (where a function documents them) are left out by value, not by
    gradient: their cotangent is 0, so a NaN inside the function still shows."""
    total = 0.0
    for i, o in enumerate(_float_leaves(out)):
        w = np.random.default_rng(i).normal(size=np.shape(o))
        total = total + jnp.sum(w * jnp.where(jnp.isfinite(o), o, 0.0))
    return total


@functools.lru_cache(maxsize=None)
def _program(label):
    """The one compiled program of an entry: ``jit(vmap(args -> (outputs, scalar, gradient)))``.

    Compilation, not running, is what this module spends its time on (the examples are tiny),
    so the jit / vmap check, the gradient check and the degenerate inputs all run this program
    (batches of two examples of one shape: a second compilation happens only for degenerate
    inputs of another shape).
    """
    c = REGISTRY[label]

    def one(*args):
        if not c.diff:
            return c.call(*args), None, None

        def scalar(*a):
            out = c.call(*a)
            return _weighted(out), out

        (value, out), grads = jax.value_and_grad(scalar, argnums=c.diff, has_aux=True)(*args)
        return out, value, grads

    return jax.jit(jax.vmap(one))


@functools.lru_cache(maxsize=None)
def _example(label, seed):
    return REGISTRY[label].build(seed)


def _run(label, examples):
    """:func:`_program` on a list of examples: ``(outputs, scalar, gradient)`` per example.

    Stacking and slicing are NumPy's: as eager JAX ops each new shape would be one more
    compilation, and this module compiles enough."""
    stacked = jax.tree_util.tree_map(lambda *x: np.stack([np.asarray(v) for v in x]), *examples)
    batched = jax.device_get(_program(label)(*stacked))
    return [jax.tree_util.tree_map(lambda x: x[i], batched) for i in range(len(examples))]


LABELS = sorted(REGISTRY)


@pytest.mark.parametrize("label", LABELS)
def test_jit_and_vmap_equal_eager(label):
    c = REGISTRY[label]
    with jax.enable_x64(True):
        examples = [_example(label, s) for s in SEEDS]
        for seed, args, (out, _, _) in zip(SEEDS, examples, _run(label, examples)):
            with jax.disable_jit():
                eager = c.call(*args)
            _assert_trees_close(out, eager, c.rtol, c.atol, f"{label}, seed {seed}")


KEYED_LABELS = [k for k in LABELS if REGISTRY[k].keys]


@pytest.mark.parametrize("label", KEYED_LABELS)
def test_pure_in_the_key(label):
    """Same key, same output (two eager calls, bit for bit); the two seeds' keys (which
    differ) give different outputs."""
    c = REGISTRY[label]
    with jax.enable_x64(True):
        examples = [_example(label, s) for s in SEEDS]
        for i, (a, b) in enumerate(zip(*examples)):
            same = all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(
                jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)))
            assert same != (i in c.keys), f"{label}: the seeds differ in other than the keys"
        with jax.disable_jit():
            first, again = c.call(*examples[0]), c.call(*examples[0])
        _assert_trees_close(first, again, 0.0, 0.0, f"{label}: same key")
        (out0, _, _), (out1, _, _) = _run(label, examples)
        differ = [not np.array_equal(np.asarray(a), np.asarray(b))
                  for a, b in zip(jax.tree_util.tree_leaves(out0),
                                  jax.tree_util.tree_leaves(out1))]
        assert any(differ), f"{label}: different keys gave the same output"


DIFF_LABELS = [k for k in LABELS if REGISTRY[k].diff]


@pytest.mark.parametrize("label", DIFF_LABELS)
def test_grad_equals_central_differences(label):
    c = REGISTRY[label]
    with jax.enable_x64(True):
        args = _example(label, 0)
        _, _, grads = _run(label, [args, _example(label, 1)])[0]
        rng = np.random.default_rng(3)
        direction = [jax.tree_util.tree_map(
            lambda x: rng.normal(size=np.shape(x)), args[i]) for i in c.diff]
        slope = sum(float(np.vdot(g, v)) for g, v in zip(jax.tree_util.tree_leaves(grads),
                                                         jax.tree_util.tree_leaves(direction)))
        h = 1e-6

        def moved(sign):
            a = list(args)
            for i, v in zip(c.diff, direction):
                a[i] = jax.tree_util.tree_map(lambda x, d: np.asarray(x) + sign * h * d, a[i], v)
            return a

        (_, plus, _), (_, minus, _) = _run(label, [moved(1.0), moved(-1.0)])
        fd = (float(plus) - float(minus)) / (2.0 * h)
        assert abs(slope - fd) <= c.fd_tol * (1.0 + abs(fd)), (label, slope, fd)


DEGENERATE = [(k, name) for k in LABELS for name, _, _ in REGISTRY[k].degenerate]


@pytest.mark.parametrize("label,name", DEGENERATE)
def test_finite_at_degenerate_inputs(label, name):
    c = REGISTRY[label]
    build, nan_documented = next((b, n) for d, b, n in c.degenerate if d == name)
    with jax.enable_x64(True):
        args = build()
        out, _, grads = _run(label, [args, args])[0]
        out = _float_leaves(out)
        if nan_documented:
            assert any(np.isnan(np.asarray(o)).any() for o in out), (label, name)
        else:
            for o in out:
                assert np.all(np.isfinite(np.asarray(o))), (label, name, o)
        for g in jax.tree_util.tree_leaves(grads):
            assert np.all(np.isfinite(np.asarray(g))), (label, name, g)
