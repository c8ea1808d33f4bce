"""Distance candidates: released lists, closed-form reduction, brute-force geometry, gradients
against finite differences, uniformity on the test layouts, bad input and the CLI."""

import dataclasses
import functools
import io
import json
from contextlib import redirect_stdout

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from gijax.candidates import (TRAIN_BASELINE, candidates_for, effective_baseline, ev_candidates,
                              fit_closed_form_baseline, gi_candidates, rig_gi_candidates,
                              step_uniformity)
from gijax.candidates.rig_aware import RigTerms, as_float_rig, solve_equal_steps
from gijax.geometry.layouts import builtin_rig, synthetic_camera
from gijax.geometry.rig import make_rig
from gijax.geometry.rotations import axis_angle_to_matrix

# Compiled without XLA's optimisation passes (conftest's quick_compiles): these checks do
# not depend on them, and they dominate this module's time.
pytestmark = pytest.mark.usefixtures("quick_compiles")

G16 = [0.5, 0.5436655530390901, 0.5933598538089077, 0.6505899686755604, 0.7174058117693126,
       0.7966693499997578, 0.892501608318949, 1.0110614299826677, 1.161983802830304,
       1.3612365930547528, 1.637348559910646, 2.0467867239341255, 2.7192485658566654,
       4.033339718346582, 7.764432455310304, 100.0]
G8 = [0.5, 0.60103325, 0.73863074, 0.94007016, 1.26849604, 1.91086214, 3.77357055, 100.0]


@pytest.fixture(autouse=True)
def x64():
    with jax.enable_x64(True):
        yield


@pytest.fixture(scope="module")
def rigs():
    return {name: builtin_rig(name) for name in ("paper-train", "paper-test2", "paper-test3")}


def two_camera_rig(b):
    """Reference at camera 0, camera 1 at distance b along x; no masks or occluder."""
    cam = synthetic_camera()
    return make_rig([cam, cam], np.tile(np.eye(3), (2, 1, 1)), [[0, 0, 0], [b, 0, 0]],
                    reference=[0, 0, 0], dtype=jnp.float64)


# Rays in the y-z plane: all perpendicular to a baseline along x.
PERP_RAYS = np.stack([np.zeros(9), np.sin(np.linspace(-1.3, 1.3, 9)),
                      np.cos(np.linspace(-1.3, 1.3, 9))], -1)


# --- closed forms -------------------------------------------------------------------------

def test_released_lists_exact():
    g16 = np.asarray(gi_candidates(16, 0.5, 100.0, TRAIN_BASELINE))
    assert g16.dtype == np.float64
    np.testing.assert_allclose(g16, G16, rtol=1e-12, atol=0)
    # The G8 list is published to 8 decimals: compare at that precision.
    g8 = np.asarray(gi_candidates(8, 0.5, 100.0, TRAIN_BASELINE))
    assert np.max(np.abs(g8 - np.asarray(G8))) <= 5e-9


def test_ev_inverse_evenly_spaced():
    d = np.asarray(ev_candidates(16))
    assert d[0] == 0.5 and d[-1] == 100.0
    np.testing.assert_allclose(1.0 / d, np.linspace(2.0, 0.01, 16), rtol=1e-14)
    assert np.all(np.diff(d) > 0)


@settings(max_examples=20, deadline=None)
@given(b=st.floats(0.05, 3.0), n=st.integers(2, 40), lo=st.floats(0.1, 2.0),
       ratio=st.floats(1.5, 500.0))
def test_closed_form_equal_parallax_steps_bruteforce(b, n, lo, ratio):
    """Angle between the viewing vectors from the far camera, by arccos of 3-D vectors."""
    d = np.asarray(gi_candidates(n, lo, lo * ratio, b))
    assert d[0] == lo and abs(d[-1] - lo * ratio) == 0 and np.all(np.diff(d) > 0)
    pts = np.stack([np.zeros(n), np.zeros(n), d], -1) - np.array([b, 0.0, 0.0])
    v = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    steps = np.arccos(np.clip(np.sum(v[:-1] * v[1:], -1), -1, 1))
    np.testing.assert_allclose(steps, steps.mean(), rtol=1e-6)


# --- rig-aware GI ---------------------------------------------------------------------------

@jax.jit
@functools.partial(jax.value_and_grad, argnums=1, has_aux=True)
def _weighted_sum_and_grad(rig, t, w):
    d = rig_gi_candidates(rig.replace(translations=t), 16, rays=PERP_RAYS)
    return jnp.sum(w * d), d


@pytest.mark.parametrize("b", [TRAIN_BASELINE, 1.0])
def test_rig_aware_reduces_to_closed_form(b):
    """Two cameras, reference at camera 0, rays perpendicular to the baseline: the rig-aware
    list is the closed form, and so is its derivative with respect to the baseline (camera 1's
    x); the reference camera (q = 0, no parallax) leaves every gradient finite."""
    rig = two_camera_rig(b)
    w = jnp.linspace(1.0, 2.0, 16)
    (_, d), g = _weighted_sum_and_grad(rig, rig.translations, w)
    d, g = np.asarray(d), np.asarray(g)
    np.testing.assert_allclose(d, np.asarray(gi_candidates(16, baseline=b)), rtol=1e-10)
    if b == TRAIN_BASELINE:
        np.testing.assert_allclose(d, G16, rtol=1e-10)
    assert np.all(np.isfinite(g))
    h = 1e-6
    fd = float(jnp.sum(w * (gi_candidates(16, baseline=b + h) - gi_candidates(16, baseline=b - h))))
    np.testing.assert_allclose(g[1, 0], fd / (2 * h), rtol=1e-6)
    assert abs(fit_closed_form_baseline(d) - b) < 1e-6 * b


def test_aggregated_steps_match_bruteforce_geometry(rigs):
    """Steps from the code vs numpy: arccos between 3-D viewing vectors, pixel scales by central
    differences of the real projection, weighted means over the code's visibility weights."""
    rig = as_float_rig(rigs["paper-test3"])
    c = np.asarray(ev_candidates(16))
    uni = step_uniformity(rig, c)
    w = np.asarray(uni["pair_weight"])
    scale = np.asarray(uni["pair_scale"])
    from gijax.geometry.panorama import Panorama, ray_grid
    rays = np.asarray(ray_grid(Panorama.hemisphere(8, 32), jnp.float64)).reshape(-1, 3)
    t = np.asarray(rig.translations)
    o = np.asarray(rig.reference)
    k = np.nonzero(w > 0)[0]
    cam_i, ray_i = np.divmod(k, rays.shape[0])
    r = rays[ray_i]
    pts = o + c[:, None, None] * r[None]  # (n, K, 3)
    v = pts - t[cam_i][None]
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    ang = np.arccos(np.clip(np.sum(v[:-1] * v[1:], -1), -1, 1))  # (n-1, K)
    # Pixel scale: rotate the far-end direction r by +-h towards the camera's offset.
    a = o - t[cam_i]
    e = a - np.sum(a * r, -1, keepdims=True) * r
    e /= np.linalg.norm(e, axis=-1, keepdims=True)
    h = 1e-6
    cam = rig.cameras[0]
    f, cx, cy = float(cam.fx), float(cam.cx), float(cam.cy)

    def equidistant(v):  # the layouts' lens, r = f * theta, re-derived here in numpy
        rho = np.linalg.norm(v[:, :2], axis=-1)
        k = f * np.arctan2(rho, v[:, 2]) / rho
        return np.stack([k * v[:, 0] + cx, k * v[:, 1] + cy], -1)

    pp = equidistant(np.cos(h) * r + np.sin(h) * e)
    pm = equidistant(np.cos(h) * r - np.sin(h) * e)
    s_fd = np.linalg.norm(pp - pm, axis=-1) / (2 * h)
    np.testing.assert_allclose(scale[k], s_fd, rtol=1e-6)
    steps = (ang * s_fd[None]) @ w[k] / w.sum()
    np.testing.assert_allclose(np.asarray(uni["steps"]), steps, rtol=1e-6)


def _slope(p, q, w, u):
    """dPhi/du of the weighted mean parallax angle, from p, q computed here in numpy."""
    return (q[None] / ((1 + p[None] * u[:, None]) ** 2 + (q[None] * u[:, None]) ** 2)) @ w


@pytest.mark.parametrize("name", ["paper-test2", "paper-test3"])
def test_gi_beats_ev_and_training_list(rigs, name):
    r"""Derived bound: if Phi is concave in u = 1/d (checked), then for EV (equal steps in u) the
    nearest step is at most Phi'(u_1) du and the farthest at least Phi'(u_{n-2}) du, so
    min/max(EV) <= Phi'(u_1) / Phi'(u_{n-2}). That bound is computed from the geometry in numpy;
    GI's ratio is 1 by construction. We assert the bound itself is clearly below 1."""
    rig = as_float_rig(rigs[name])
    n = 16
    ev = ev_candidates(n)
    gi = rig_gi_candidates(rig, n)
    train = gi_candidates(n, baseline=TRAIN_BASELINE)
    u_ev, u_gi, u_tr = (step_uniformity(rig, c) for c in (ev, gi, train))

    w = np.asarray(u_ev["pair_weight"] * u_ev["pair_scale"])
    from gijax.geometry.panorama import Panorama, ray_grid
    rays = np.asarray(ray_grid(Panorama.hemisphere(8, 32), jnp.float64)).reshape(-1, 3)
    a = np.asarray(rig.reference)[None] - np.asarray(rig.translations)  # (C, 3)
    p = (a @ rays.T).reshape(-1)
    q = np.linalg.norm(np.cross(a[:, None], rays[None]), axis=-1).reshape(-1)
    grid = np.linspace(0.01, 2.0, 400)
    slope = _slope(p, q, w, grid)
    assert np.all(np.diff(slope) < 0), "premise of the bound: Phi concave in 1/d"
    u = 1.0 / np.asarray(ev)
    bound = _slope(p, q, w, u[1:2])[0] / _slope(p, q, w, u[n - 2:n - 1])[0]
    assert bound < 0.8
    assert float(u_ev["min_max_ratio"]) <= bound
    assert float(u_gi["min_max_ratio"]) >= 1 - 1e-9
    assert float(u_gi["cv"]) < 1e-9 and float(u_ev["cv"]) > 0.1
    # The training-rig list applied to the new rig is less uniform, on average and per ray.
    assert float(u_tr["min_max_ratio"]) < 0.9 and float(u_tr["cv"]) > 0.03
    assert float(u_gi["ray_cv"]) < float(u_tr["ray_cv"]) < float(u_ev["ray_cv"])
    assert float(u_gi["ray_cv"]) < 0.85 * float(u_ev["ray_cv"])


def test_effective_baselines(rigs):
    b2 = effective_baseline(rigs["paper-test2"])
    b3 = effective_baseline(rigs["paper-test3"])
    # Centroid references 0.577 m and 0.707 m from the cameras; the mean perpendicular offset
    # over the hemisphere is smaller, and the square rig's is the larger.
    assert 0.2 < b2 < b3 < 0.707
    assert abs(fit_closed_form_baseline(gi_candidates(16, baseline=0.7)) - 0.7) < 1e-6
    # EV is the b -> 0 limit of the closed form.
    assert fit_closed_form_baseline(ev_candidates(16)) == 0.0
    # Reference at camera 0: rays towards and away from another camera bend Phi(1/d) in
    # opposite directions (p -> -p flips the u^2 term of atan2(q u, 1 + p u)), so over the
    # hemisphere the mean is nearly linear in 1/d and the list is EV-like.
    assert effective_baseline(rigs["paper-train"]) == 0.0


# --- derivatives ----------------------------------------------------------------------------

def _perturbed(rig, dt, dw, dk):
    """The rig with translations + dt, rotations R exp(dw), intrinsics (fx, fy, cx, cy) + dk."""
    cams = tuple(dataclasses.replace(c, fx=c.fx + dk[i, 0], fy=c.fy + dk[i, 1],
                                     cx=c.cx + dk[i, 2], cy=c.cy + dk[i, 3])
                 for i, c in enumerate(rig.cameras))
    return rig.replace(translations=rig.translations + dt,
                       rotations=rig.rotations @ axis_angle_to_matrix(dw), cameras=cams)


def test_gradients_match_finite_differences(rigs):
    # paper-test3 made asymmetric (the square's symmetry cancels some derivatives exactly):
    # shifted cameras and reference, a different focal length per camera, small tilts.
    rng = np.random.default_rng(0)
    base = _perturbed(as_float_rig(rigs["paper-test3"]), rng.normal(0, 0.05, (4, 3)) * [1, 1, 0],
                      rng.normal(0, 0.05, (4, 3)),
                      np.stack([rng.normal(0, 15, 4)] * 2 + [np.zeros(4)] * 2, -1))
    base = base.replace(reference=base.reference + jnp.array([0.03, -0.02, 0.0]))
    n = 16
    coef = jnp.asarray(rng.normal(size=n))

    def loss(rig, dt, dw, dk):
        return jnp.sum(coef * jnp.log(rig_gi_candidates(_perturbed(rig, dt, dw, dk), n)))

    # One compiled function serves the gradient and the finite differences.
    value_and_grad = jax.jit(jax.value_and_grad(loss, argnums=(1, 2, 3)))
    f = lambda *args: value_and_grad(*args)[0]
    zeros = (np.zeros((4, 3)), np.zeros((4, 3)), np.zeros((4, 4)))
    grads = value_and_grad(base, *zeros)[1]
    # Central differences along three random directions per parameter group (translations m,
    # rotation vectors rad, intrinsics px).
    steps = (1e-6, 1e-6, 1e-4)
    for arg, (g, h) in enumerate(zip(grads, steps)):
        g = np.asarray(g)
        assert np.all(np.isfinite(g)) and np.max(np.abs(g)) > 1e-6
        for v in rng.normal(size=(3,) + g.shape):
            plus = list(zeros)
            minus = list(zeros)
            plus[arg] = h * v
            minus[arg] = -h * v
            fd = (float(f(base, *plus)) - float(f(base, *minus))) / (2 * h)
            np.testing.assert_allclose(np.sum(g * v), fd, rtol=1e-4)


# --- bad input ----------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs,field", [
    (dict(n=1), "n"), (dict(n=2.5), "n"), (dict(d_min=0.0), "d_min"), (dict(d_min=-1.0), "d_min"),
    (dict(d_min=5.0, d_max=5.0), "d_min"), (dict(d_max=float("nan")), "d_max"),
])
@pytest.mark.parametrize("kind", ["ev", "gi-closed", "gi"])
def test_bad_arguments(rigs, kwargs, field, kind):
    args = dict(n=16, d_min=0.5, d_max=100.0) | kwargs
    with pytest.raises(ValueError, match=field):
        candidates_for(kind, args["n"], rigs["paper-test2"], args["d_min"], args["d_max"])


@pytest.mark.parametrize("field", ["translations", "rotations", "reference"])
def test_non_finite_calibration_is_an_error_not_nan_candidates(rigs, field):
    rig = rigs["paper-test2"]
    bad = np.array(getattr(rig, field), np.float64)
    bad.flat[1] = np.nan if field != "reference" else np.inf
    with pytest.raises(ValueError, match="NaN or infinite"):
        rig_gi_candidates(rig.replace(**{field: jnp.asarray(bad, jnp.float32)}), 16)


def test_rig_without_overlap(rigs):
    # paper-test2 with 80-degree lenses looking up, down and sideways: no common ray.
    rig = rigs["paper-test2"]
    look = [np.eye(3), np.diag([1.0, -1.0, -1.0]),
            np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])]
    cams = tuple(dataclasses.replace(c, fov=jnp.deg2rad(jnp.float32(80.0))) for c in rig.cameras)
    rig = rig.replace(cameras=cams, rotations=jnp.asarray(np.stack(look), jnp.float32))
    with pytest.raises(ValueError, match="rig: no panorama ray"):
        rig_gi_candidates(rig, 16)
    # Under a trace the check cannot raise: the solver returns NaN, never a plausible list.
    zero = RigTerms(*(jnp.zeros(4) for _ in range(2)), jnp.zeros(4), jnp.ones(4))
    out = jax.jit(lambda t: solve_equal_steps(t, 8, 0.5, 100.0))(zero)
    assert np.all(np.isnan(np.asarray(out)))
    with pytest.raises(ValueError, match="ascending"):
        step_uniformity(rigs["paper-test2"], [0.5, 2.0, 1.0])
    with pytest.raises(ValueError, match="kind"):
        candidates_for("uniform", 8)


def test_checks_under_a_trace(rigs):
    from jax.experimental import checkify

    from gijax.candidates import camera_spacing, check_candidates
    from gijax.geometry.panorama import Panorama

    small = dict(pano=Panorama.hemisphere(2, 4), samples=2)
    cam = synthetic_camera(16, 300.0 / 64.0)
    same = make_rig([cam, cam], np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3)),
                    dtype=jnp.float64)
    # Gradient through a rig without coverage: no error while tracing, NaN list, zero gradient.
    loss = lambda t: jnp.nansum(rig_gi_candidates(same.replace(translations=t), 4, **small))
    grad = jax.grad(loss)(same.translations)
    np.testing.assert_array_equal(np.asarray(grad), 0.0)
    # checkify turns the trace-time check into the same error eager calls raise.
    err, d = checkify.checkify(jax.jit(lambda r: rig_gi_candidates(r, 4, **small)))(same)
    assert np.all(np.isnan(np.asarray(d)))
    with pytest.raises(checkify.JaxRuntimeError, match="rig: no panorama ray"):
        err.throw()
    err, _ = checkify.checkify(jax.jit(camera_spacing))(jnp.zeros((3, 3)))
    with pytest.raises(checkify.JaxRuntimeError, match="share a centre"):
        err.throw()
    err, _ = checkify.checkify(jax.jit(lambda c: step_uniformity(rigs["paper-test2"], c,
                                                                 **small)))(
        jnp.asarray([0.5, 2.0, 1.0]))
    with pytest.raises(checkify.JaxRuntimeError, match="strictly ascending"):
        err.throw()
    # The one eager check of a list names what is wrong.
    np.testing.assert_array_equal(check_candidates([0.5, 1.0, 2.0]), [0.5, 1.0, 2.0])
    for bad, why in (([0.5, 0.5, 2.0], "strictly ascending"), ([0.0, 1.0], "> 0 m"),
                     ([0.5, float("inf")], "finite"), ([[0.5, 1.0]], "1-D"), ([0.5], "at least 2")):
        with pytest.raises(ValueError, match=why):
            check_candidates(bad)
    with pytest.raises(ValueError, match="hold 3 distances"):
        check_candidates([0.5, 1.0], count=3)


# --- command line ---------------------------------------------------------------------------

def test_cli_json_and_plot(tmp_path):
    from gijax.cli import main

    png = tmp_path / "cand.png"
    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = main(["candidates", "--rig", "paper-test2", "-n", "16", "--json", "--plot",
                   str(png)])
    assert rc == 0
    out = json.loads(buf.getvalue())
    c = np.asarray(out["candidates"])
    assert c.shape == (16,) and c[0] == 0.5 and c[-1] == 100.0 and np.all(np.diff(c) > 0)
    assert out["cv"] < 1e-9 and abs(out["min_max_ratio"] - 1) < 1e-9 and len(out["steps"]) == 15
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = main(["candidates", "--rig", "paper-train", "--kind", "gi-closed", "--json"])
    np.testing.assert_allclose(json.loads(buf.getvalue())["candidates"], G16, rtol=1e-12)
    assert main(["candidates", "--rig", "paper-train", "-n", "1"]) == 1


# --------------------------------------------------------------------------- camera spacing

def test_spacing_list_is_released_g16_on_training_rig(rigs):
    from gijax.candidates import camera_spacing, spacing_gi_candidates

    # The training triangle's side is the released lists' baseline (float32 translations).
    assert float(camera_spacing(rigs["paper-train"])) == pytest.approx(TRAIN_BASELINE, rel=1e-7)
    np.testing.assert_allclose(spacing_gi_candidates(rigs["paper-train"], 16), G16, rtol=1e-7)
    np.testing.assert_allclose(candidates_for("gi-spacing", 8, rigs["paper-train"]), G8,
                               rtol=1e-7)
    # The 1 m layouts: the closed form at b = 1 m, which differs from the training list.
    for name in ("paper-test2", "paper-test3"):
        assert float(camera_spacing(rigs[name])) == pytest.approx(1.0, rel=1e-7)
        np.testing.assert_allclose(candidates_for("gi-spacing", 16, rigs[name]),
                                   gi_candidates(16, 0.5, 100.0, 1.0), rtol=1e-7)


@settings(max_examples=25, deadline=None)
@given(pts=st.lists(st.tuples(*[st.floats(-2.0, 2.0)] * 3), min_size=2, max_size=6))
def test_camera_spacing_matches_brute_force(pts):
    from gijax.candidates import camera_spacing

    t = np.asarray(pts, np.float64)
    gaps = [min(np.linalg.norm(t[i] - t[j]) for j in range(len(t)) if j != i)
            for i in range(len(t))]
    if min(gaps) < 1e-3:                       # coincident centres are rejected (tested below)
        return
    assert float(camera_spacing(t)) == pytest.approx(float(np.mean(gaps)), rel=1e-12)


def test_camera_spacing_gradient_matches_finite_differences():
    from gijax.candidates import spacing_gi_candidates

    rig = builtin_rig("paper-test3")
    t0 = np.asarray(rig.translations, np.float64) + np.array([[0.1, 0, 0], [0, 0.05, 0],
                                                              [0, 0, 0], [0.02, 0.03, 0]])

    def f(t):
        return jnp.sum(jnp.log(spacing_gi_candidates(rig.replace(translations=t), 16)[1:-1]))

    g = np.asarray(jax.grad(f)(jnp.asarray(t0)))
    assert np.all(np.isfinite(g)) and np.abs(g).max() > 0
    eps = 1e-6
    for idx in [(0, 0), (1, 1), (3, 0), (2, 1)]:
        tp, tm = t0.copy(), t0.copy()
        tp[idx] += eps
        tm[idx] -= eps
        fd = (float(f(jnp.asarray(tp))) - float(f(jnp.asarray(tm)))) / (2 * eps)
        assert g[idx] == pytest.approx(fd, rel=1e-5, abs=1e-9)


def test_camera_spacing_bad_input():
    from gijax.candidates import camera_spacing

    with pytest.raises(ValueError, match="at least 2 cameras"):
        camera_spacing(np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        camera_spacing(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="share a centre"):
        camera_spacing(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="needs a rig"):
        candidates_for("gi-spacing", 16)


def test_eval_and_predict_candidate_specs(rigs):
    from gijax.candidates.spec import resolve_candidates

    rig = rigs["paper-test2"]
    want = {"spacing": gi_candidates(16, 0.5, 100.0, 1.0), "ev": ev_candidates(16),
            "rig": rig_gi_candidates(rig, 16)}
    for spec, expected in want.items():
        got, label = resolve_candidates(spec, rig, 16, train=G16)
        np.testing.assert_allclose(got, expected, rtol=1e-6)
        assert label
    np.testing.assert_allclose(resolve_candidates("train", rig, 16, train=G16)[0], G16)
