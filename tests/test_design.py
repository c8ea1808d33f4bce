"""Rig design: objective gradients, visibility surrogates, constraints and the optimiser."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from gijax.design import (DesignSpec, at_least_two, constraint_report, evaluate_layouts,
                          is_feasible, layout_rig, make_layout, objective_terms,
                          occluder_margin, optimize_layout, penalty, random_layouts,
                          regular_layout, stack_layouts, violations)
from gijax.geometry.occluder import Cylinder, cylinder_hit
from gijax.geometry.panorama import Panorama

# Compiled without XLA's optimisation passes (conftest's quick_compiles): these checks do
# not depend on them, and they dominate this module's time.
pytestmark = pytest.mark.usefixtures("quick_compiles")

# Small ray grid and list: the tests exercise the same code paths at a fraction of the cost.
SMALL = dict(pano=Panorama.hemisphere(4, 8), num_candidates=8, samples=2)


# ---------------------------------------------------------------- gradients vs finite differences

@pytest.fixture(scope="module")
def grad_case():
    spec = DesignSpec(num_cameras=3, heights=True, **SMALL)
    with jax.enable_x64(True):
        lay = make_layout([[0.31, 0.12], [-0.22, 0.27], [0.05, -0.36]], heights=[0.02, 0.05, 0.0],
                          rotvecs=[[0.10, -0.05, 0.20], [-0.08, 0.12, -0.1], [0.04, 0.07, 0.3]],
                          dtype=jnp.float64)
        f = jax.jit(lambda lay: objective_terms(lay, spec)["objective"])
        g = jax.jit(jax.grad(lambda lay: objective_terms(lay, spec)["objective"]))
        grad = g(lay)
        fd = {}
        h = 1e-6
        for field in ("positions", "heights", "rotvecs"):
            x = np.asarray(getattr(lay, field))
            out = np.zeros_like(x)
            for idx in np.ndindex(x.shape):
                e = np.zeros_like(x)
                e[idx] = h
                plus = float(f(lay.replace(**{field: jnp.asarray(x + e)})))
                minus = float(f(lay.replace(**{field: jnp.asarray(x - e)})))
                out[idx] = (plus - minus) / (2 * h)
            fd[field] = out
        value = float(f(lay))
    return spec, grad, fd, value


@pytest.mark.parametrize("field", ["positions", "heights", "rotvecs"])
def test_gradient_matches_central_differences(grad_case, field):
    _, grad, fd, value = grad_case
    g = np.asarray(getattr(grad, field))
    assert np.all(np.isfinite(g)) and value > 0
    scale = max(np.abs(fd["positions"]).max(), np.abs(fd["rotvecs"]).max())
    assert np.abs(g).max() > 1e-3 * scale  # the parameters do move the objective
    # Relative to the largest gradient entry: 1e-5 (the central difference's own error with
    # h = 1e-6 in float64 is far below that).
    np.testing.assert_allclose(g, fd[field], rtol=0, atol=1e-5 * scale)


# ---------------------------------------------------------------- visibility surrogates

@settings(max_examples=20, deadline=None)
@given(st.integers(1, 5), st.data())
def test_at_least_two_matches_enumeration(c, data):
    v = np.asarray(data.draw(st.lists(st.floats(0, 1), min_size=c, max_size=c)))
    # Brute force over every subset of cameras that sees the ray.
    want = 0.0
    for seen in itertools.product([0, 1], repeat=c):
        p = np.prod([vi if s else 1 - vi for vi, s in zip(v, seen)])
        want += p * (sum(seen) >= 2)
    got = float(at_least_two(jnp.asarray(v, jnp.float32)[:, None])[0])
    assert got == pytest.approx(want, abs=1e-6)


def test_occluder_margin_sign_matches_ray_cylinder_hits():
    spec = DesignSpec()
    rng = np.random.default_rng(0)
    origins = np.concatenate([rng.uniform(-0.4, 0.4, (400, 2)), rng.uniform(0, 0.15, (400, 1))], 1)
    origins = origins[np.linalg.norm(origins[:, :2], axis=1) > 0.06]
    # Aim through random points around the cylinder, and stop short of it or go past it.
    aim = np.concatenate([rng.uniform(-0.1, 0.1, (len(origins), 2)),
                          rng.uniform(-0.05, 0.2, (len(origins), 1))], 1)
    targets = origins + rng.uniform(0.3, 2.0, (len(origins), 1)) * (aim - origins)
    margin = np.asarray(occluder_margin(spec, jnp.asarray(origins), jnp.asarray(targets)))
    cyl = Cylinder(*(jnp.float32(v) for v in (0, 0, spec.occluder_radius, 0,
                                               spec.occluder_height)))
    v = targets - origins
    length = np.linalg.norm(v, axis=1)
    hit = np.asarray(cylinder_hit(cyl, jnp.asarray(origins), jnp.asarray(v / length[:, None])))
    blocked = hit < length
    clear = np.abs(margin) > 1e-4  # away from grazing segments, where float32 may differ
    assert blocked[clear].sum() > 20 and (~blocked[clear]).sum() > 20
    np.testing.assert_array_equal(margin[clear] < 0, blocked[clear])


# ---------------------------------------------------------------- constraints

def _worst_violation(xy, spec):
    """Largest constraint violation of the positions, metres (<= 0: feasible), by brute force."""
    xy = np.asarray(xy, np.float64)
    h = spec.half_size
    out = (np.abs(xy).max() - h) if spec.shape == "square" else (np.linalg.norm(xy, axis=1).max()
                                                                 - h)
    d = min(np.linalg.norm(a - b) for a, b in itertools.combinations(xy, 2))
    occ = np.linalg.norm(xy, axis=1).min()
    return max(out, spec.min_separation - d,
               spec.occluder_radius + spec.occluder_clearance - occ)


def _brute_force_feasible(xy, spec):
    return _worst_violation(xy, spec) <= 0.0


@settings(max_examples=25, deadline=None)
@given(st.sampled_from(["square", "disc"]), st.integers(2, 5), st.data())
def test_penalty_is_zero_exactly_for_feasible_layouts(shape, n, data):
    spec = DesignSpec(num_cameras=n, shape=shape, orientations=False, footprint=1.0)
    xy = np.asarray(data.draw(st.lists(st.tuples(st.floats(-0.7, 0.7), st.floats(-0.7, 0.7)),
                                       min_size=n, max_size=n)))
    with jax.enable_x64(True):
        lay = make_layout(xy, dtype=jnp.float64)
        pen = float(penalty(lay, spec))
        worst = _worst_violation(xy, spec)
        if worst <= 0.0:
            assert pen == 0.0 and is_feasible(lay, spec)
        else:
            assert pen > 0.0
        if worst > 1e-9:  # is_feasible allows rounding-level violations (1e-9 m)
            assert not is_feasible(lay, spec)


def test_penalty_terms_tilt_height_and_slack():
    spec = DesignSpec(num_cameras=2, heights=True, max_tilt_deg=20.0, height_range=(0.0, 0.1))
    base = dict(positions=[[0.4, 0.0], [-0.4, 0.0]], heights=[0.05, 0.05])
    ok = make_layout(**base, rotvecs=[[math.radians(19.0), 0, 0], [0, 0, 2.0]])
    assert float(penalty(ok, spec)) == 0.0  # yaw is free, 19 degrees of tilt allowed
    tilted = make_layout(**base, rotvecs=[[0, math.radians(25.0), 0], [0, 0, 0]])
    v = violations(tilted, spec)
    want = math.cos(math.radians(20.0)) - math.cos(math.radians(25.0))
    assert float(v["tilt"][0]) == pytest.approx(want, rel=1e-5)
    high = make_layout(positions=base["positions"], heights=[0.13, 0.05])
    assert float(violations(high, spec)["height"][0]) == pytest.approx(0.03, abs=1e-6)
    # Slack tightens the separation: 0.2 m apart is feasible, but not with 5 mm of slack.
    close = make_layout([[0.1, 0.3], [-0.1, 0.3]], heights=[0.05, 0.05])
    assert float(penalty(close, spec)) == 0.0
    assert float(penalty(close, spec, slack=0.005)) == pytest.approx(0.005 ** 2, rel=1e-3)


def test_spec_rejects_bad_values():
    with pytest.raises(ValueError, match="shape"):
        DesignSpec(shape="hexagon")
    with pytest.raises(ValueError, match="num_cameras"):
        DesignSpec(num_cameras=1)
    with pytest.raises(ValueError, match="positions must have shape"):
        make_layout(np.zeros((3, 3)))


# ---------------------------------------------------------------- optimisation

@pytest.fixture(scope="module")
def optimised():
    spec = DesignSpec(num_cameras=3, max_tilt_deg=15.0, **SMALL)
    # Start 0 is the regular layout of the footprint, the others are random.
    starts = random_layouts(jax.random.PRNGKey(3), spec, 3)
    regular = regular_layout(spec)
    starts = jax.tree_util.tree_map(lambda s, r: s.at[0].set(r), starts, regular)
    res = optimize_layout(spec, steps=25, lr=0.05, init=starts, progress=False)
    return spec, res


def test_optimisation_improves_every_start(optimised):
    _, res = optimised
    first, last = res.history[0], res.history[-1]
    assert np.all(last < first)
    assert res.evaluations == 3 * 26
    evals, best = res.best_so_far()
    assert np.all(np.diff(best) <= 0) and evals[-1] == res.evaluations


def test_optimised_layout_satisfies_constraints(optimised):
    spec, res = optimised
    xy = np.asarray(res.best.positions, np.float64)
    assert _brute_force_feasible(xy, spec)
    rot = jnp.asarray(res.best.rotvecs)
    from gijax.geometry.rotations import axis_angle_to_matrix
    tilt = np.degrees(np.arccos(np.asarray(axis_angle_to_matrix(rot))[:, 2, 2]))
    assert np.all(tilt <= spec.max_tilt_deg + 1e-4)
    rep = constraint_report(res.best, spec)
    assert rep["feasible"] and rep["min_separation"] >= spec.min_separation


def test_optimised_beats_the_regular_layout_of_the_footprint(optimised):
    """Three cameras in a 1 m square: the centred equilateral triangle that fits (side 0.87 m)
    is not a stationary point of the objective; the optimiser improves on it."""
    spec, res = optimised
    regular = evaluate_layouts(stack_layouts([regular_layout(spec)]), spec, 3)
    assert res.history[0, 0] == pytest.approx(float(regular["total"][0]), rel=1e-5)
    assert res.best_terms["objective"] < 0.97 * float(regular["objective"][0])


def test_hard_coverage_matches_rig_projection_and_masks(optimised):
    """The 0/1 limit of the surrogate equals what the rig's own projection and occlusion masks
    say: a ray counts when two cameras see its swept points at every sample distance and the
    swept segment keeps d_min / 2 away from the lens."""
    from gijax.geometry.panorama import lonlat_grid, ray_grid
    from gijax.geometry.rig import project_rig_points

    spec, _ = optimised
    lay = make_layout([[0.3, 0.0], [-0.2, 0.3], [-0.1, -0.35]],
                      rotvecs=[[0.0, 0.6, 0.0], [0.0, 0.6, 0.0], [0.0, 0.0, 0.0]])
    # Same spec and batch as the optimiser's final evaluation: no new compilation.
    got = float(evaluate_layouts(stack_layouts([lay]), spec, 3)["hard_coverage"][0])
    rig = layout_rig(lay, spec, image_scale=0.25)
    rays = np.asarray(ray_grid(spec.pano)).reshape(-1, 3)
    _, lat = lonlat_grid(spec.pano)
    w = np.cos(np.asarray(lat)).reshape(-1)
    ds = spec.d_min * (spec.d_max / spec.d_min) ** np.linspace(0, 1, spec.samples)
    pts = np.asarray(rig.reference) + ds[:, None, None] * rays[None]
    _, ok = project_rig_points(rig, jnp.asarray(pts, jnp.float32))
    seen = np.asarray(ok).all(axis=1)  # (C, R)
    # Closest approach of the swept segment to each camera centre, by dense sampling.
    dense = spec.d_min * (spec.d_max / spec.d_min) ** np.linspace(0, 1, 4000)
    sweep = np.asarray(rig.reference) + dense[:, None, None] * rays[None]  # (D, R, 3)
    t = np.asarray(rig.translations)
    closest = np.linalg.norm(sweep[None] - t[:, None, None], axis=-1).min(axis=1)  # (C, R)
    seen &= closest >= 0.5 * spec.d_min
    want = float(np.sum(w * (seen.sum(0) >= 2)) / w.sum())
    assert 0.3 < want < 1.0  # the tilts and the occluder make this a real test
    assert got == pytest.approx(want, abs=1.5 / rays.shape[0])
