"""Layout search: multi-start Adam on the penalised objective, random search, grid search.

The objective and penalty are pure and jitted; the loops here are the only side-effecting code
(a tqdm progress bar). Traceable (jit, vmap, grad in the layouts; spec static):
:func:`total_loss`, :func:`batch_report`, :func:`stack_layouts`, :func:`index_layout` and
:func:`random_layouts` (in its key). The searches (:func:`optimize_layout`,
:func:`random_search`, :func:`grid_search`), :func:`evaluate_layouts` (chunked, NumPy out),
:func:`terms_to_python`, :func:`grid_points`, :func:`regular_layout` (NumPy geometry of the
spec) and :func:`layout_rig` (a concrete rig with rendered masks) are the eager edges.

Evaluation accounting, used to compare the methods at equal cost: one *evaluation* is one value
of the penalised objective for one layout; a gradient step counts as one evaluation (its value)
plus its gradient, which reverse-mode differentiation delivers for a small constant multiple of
the value's cost (measured and reported by the experiment script).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax

from gijax.design.constraints import penalty, project
from gijax.design.objective import layout_pose, objective_terms
from gijax.design.spec import DesignSpec, Layout, make_layout
from gijax.geometry.layouts import synthetic_camera
from gijax.geometry.occluder import Cylinder
from gijax.geometry.rig import Rig, make_rig, scale_rig, with_occlusion_masks

Array = jax.Array


def total_loss(layout: Layout, spec: DesignSpec) -> Array:
    """Objective J plus ``penalty_weight`` times the (slack-tightened) constraint penalty."""
    return objective_terms(layout, spec)["objective"] + spec.penalty_weight * penalty(
        layout, spec, spec.slack)


@functools.partial(jax.jit, static_argnames=("spec",))
def batch_report(layouts: Layout, spec: DesignSpec) -> dict:
    """:func:`objective_terms` of a batch of layouts plus ``penalty`` (slack-tightened, as the
    optimiser uses it) and ``total`` (the penalised objective), each with a leading axis."""

    def one(lay):
        terms = objective_terms(lay, spec)
        pen = penalty(lay, spec, spec.slack)
        return {**terms, "penalty": pen,
                "total": terms["objective"] + spec.penalty_weight * pen}

    return jax.vmap(one)(layouts)


def evaluate_layouts(layouts: Layout, spec: DesignSpec, batch: int = 8) -> dict:
    """:func:`batch_report` of any number of layouts, ``batch`` at a time: the last chunk is
    padded, so one compilation serves every call with the same ``batch``. numpy arrays."""
    total = layouts.positions.shape[0]
    parts = []
    for s in range(0, total, batch):
        chunk = jax.tree_util.tree_map(lambda x: x[s:s + batch], layouts)
        m = chunk.positions.shape[0]
        if m < batch:
            chunk = jax.tree_util.tree_map(
                lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], batch - m, axis=0)]), chunk)
        rep = batch_report(chunk, spec)
        parts.append({k: np.asarray(v)[:m] for k, v in rep.items()})
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def stack_layouts(layouts) -> Layout:
    """A batched Layout from a sequence of single layouts."""
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *layouts)


def index_layout(layouts: Layout, i: int) -> Layout:
    """Layout ``i`` of a batch."""
    return jax.tree_util.tree_map(lambda x: x[i], layouts)


def random_layouts(key, spec: DesignSpec, count: int, dtype=jnp.float32) -> Layout:
    """``count`` layouts drawn uniformly: positions over the footprint's area, heights over their
    range, optical axes tilted by an angle uniform in [0, max_tilt] towards a uniform azimuth
    (zero tilt when orientations are fixed). Separation and occluder are not enforced."""
    n = spec.num_cameras
    k_pos, k_rad, k_h, k_tilt, k_az = jax.random.split(key, 5)
    half = spec.half_size
    if spec.shape == "square":
        pos = jax.random.uniform(k_pos, (count, n, 2), dtype, -half, half)
    else:
        ang = jax.random.uniform(k_pos, (count, n), dtype, 0.0, 2 * math.pi)
        rad = half * jnp.sqrt(jax.random.uniform(k_rad, (count, n), dtype))
        pos = jnp.stack([rad * jnp.cos(ang), rad * jnp.sin(ang)], -1)
    lo, hi = spec.height_range
    heights = (jax.random.uniform(k_h, (count, n), dtype, lo, hi) if spec.heights
               else jnp.zeros((count, n), dtype))
    tilt = jax.random.uniform(k_tilt, (count, n), dtype, 0.0, math.radians(spec.max_tilt_deg))
    az = jax.random.uniform(k_az, (count, n), dtype, 0.0, 2 * math.pi)
    rot = jnp.stack([tilt * jnp.cos(az), tilt * jnp.sin(az), jnp.zeros_like(tilt)], -1)
    if not spec.orientations:
        rot = jnp.zeros_like(rot)
    return Layout(pos, heights, rot)


def regular_layout(spec: DesignSpec, dtype=jnp.float32) -> Layout:
    """The paper-style layout for the spec's camera count: a regular polygon centred on the
    footprint (3: triangle with a vertex on +y as paper-test2; 4: square with its corners on
    the diagonals as paper-test3; others: the same rule, a vertex on +y), the largest that fits
    the footprint; all cameras looking along +z at z = 0."""
    n = spec.num_cameras
    start = 45.0 if n == 4 else 90.0
    ang = np.radians(start + 360.0 * np.arange(n) / n)
    c, s = np.cos(ang), np.sin(ang)
    if spec.shape == "square":
        radius = spec.half_size / float(np.max(np.maximum(np.abs(c), np.abs(s))))
    else:
        radius = spec.half_size
    return make_layout(np.stack([radius * c, radius * s], -1), dtype=dtype)


def layout_rig(layout: Layout, spec: DesignSpec, masks: bool = True,
               image_scale: float = 1.0) -> Rig:
    """The rig of a (single) layout: the spec's camera, the layout's poses, the reference point
    at the centroid, the occluder at the footprint's centre, and (``masks=True``) self-occlusion
    masks; images resized by ``image_scale``."""
    rot, trans, ref = layout_pose(layout, spec)
    n = spec.num_cameras
    occ = Cylinder(*(np.float32(v) for v in (0.0, 0.0, spec.occluder_radius, 0.0,
                                             spec.occluder_height)))
    cams = [synthetic_camera(spec.camera_size, spec.focal, spec.fov_deg) for _ in range(n)]
    rig = make_rig(cams, np.asarray(rot, np.float64), np.asarray(trans, np.float64),
                   np.asarray(ref, np.float64), occluder=occ)
    if image_scale != 1.0:
        rig = scale_rig(rig, image_scale)
    return with_occlusion_masks(rig) if masks else rig


@dataclasses.dataclass
class DesignResult:
    """Outcome of :func:`optimize_layout` (numpy / Python values).

    best: the best final layout; layouts: all final layouts (batched, K starts);
    final: (K,) penalised objective of the final layouts; history: (steps + 1, K) penalised
    objective at every iterate (row 0 = the starts, last row = the final layouts);
    evaluations: objective evaluations used (K * (steps + 1)); seconds: wall time;
    best_terms: :func:`batch_report` entries of ``best`` as floats (candidates as a list).
    """

    best: Layout
    layouts: Layout
    final: np.ndarray
    history: np.ndarray
    evaluations: int
    seconds: float
    best_terms: dict

    def best_so_far(self) -> tuple[np.ndarray, np.ndarray]:
        """(evaluations, best penalised objective reached so far), one entry per step."""
        evals = self.history.shape[1] * np.arange(1, self.history.shape[0] + 1)
        return evals, np.minimum.accumulate(self.history.min(axis=1))


def terms_to_python(terms: dict) -> dict:
    """:func:`objective_terms` output as floats and lists (concrete values, not traced)."""
    return {k: (np.asarray(v).tolist() if np.ndim(v) else float(v)) for k, v in terms.items()}


@functools.lru_cache(maxsize=16)
def adam_step(spec: DesignSpec, lr: float, steps: int):
    """``(tx, step)``: the Adam transform (cosine-decayed from ``lr`` over ``steps``) and the
    compiled step ``step(layouts, opt_state) -> (layouts, opt_state, losses)`` of a batch of
    layouts, projected onto the footprint after each update. Cached per (spec, lr, steps), so
    every caller shares one compiled program."""
    schedule = optax.cosine_decay_schedule(lr, max(steps, 1), alpha=0.05)
    tx = optax.adam(schedule)
    value_grad = jax.vmap(jax.value_and_grad(lambda lay: total_loss(lay, spec)))

    @jax.jit
    def step(layouts, opt_state):
        value, grad = value_grad(layouts)
        upd, opt_state = tx.update(grad, opt_state, layouts)
        layouts = project(optax.apply_updates(layouts, upd), spec)
        return layouts, opt_state, value

    return tx, step


def optimize_layout(spec: DesignSpec, starts: int = 8, steps: int = 200, seed: int = 0,
                    lr: float = 0.02, init: Layout | None = None, progress: bool = True,
                    dtype=jnp.float32) -> DesignResult:
    """Minimise the penalised objective with Adam from ``starts`` random layouts in parallel.

    ``lr`` is the initial step (metres / radians), decayed by a cosine schedule to 5 %.
    ``init`` (a batched Layout) replaces the random starts. Every iterate is projected onto the
    footprint (and height range); separation, occluder and tilt are held by the penalty.
    """
    from tqdm import tqdm

    if starts < 1 or steps < 0:
        raise ValueError(f"starts must be >= 1 and steps >= 0; found starts={starts}, "
                         f"steps={steps}")
    t0 = time.perf_counter()
    if init is None:
        init = random_layouts(jax.random.PRNGKey(seed), spec, starts, dtype)
    layouts = project(jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), init), spec)
    k = layouts.positions.shape[0]
    tx, step = adam_step(spec, float(lr), int(steps))
    opt_state = tx.init(layouts)
    history = []
    for _ in tqdm(range(steps), desc=f"design {spec.num_cameras} cameras, {k} starts",
                  disable=not progress, leave=False):
        layouts, opt_state, value = step(layouts, opt_state)
        history.append(np.asarray(value))
    report = evaluate_layouts(layouts, spec, k)
    final = report["total"]
    history.append(final)
    i = int(np.nanargmin(final))
    best = index_layout(layouts, i)
    terms = terms_to_python({key: v[i] for key, v in report.items()})
    return DesignResult(best=best, layouts=layouts, final=final, history=np.stack(history),
                        evaluations=k * (steps + 1), seconds=time.perf_counter() - t0,
                        best_terms=terms)


def random_search(spec: DesignSpec, evaluations: int, seed: int = 0, batch: int = 8,
                  dtype=jnp.float32) -> dict:
    """Best of ``evaluations`` random layouts (:func:`random_layouts`).

    Returns ``best`` (Layout), ``values`` (E,) penalised objective in drawing order,
    ``best_so_far`` (E,), ``evaluations`` and ``seconds``.
    """
    t0 = time.perf_counter()
    lays = random_layouts(jax.random.PRNGKey(seed + 1_000_003), spec, evaluations, dtype)
    vals = evaluate_layouts(lays, spec, batch)["total"]
    i = int(np.nanargmin(vals))
    return {"best": index_layout(lays, i), "values": vals,
            "best_so_far": np.minimum.accumulate(vals), "evaluations": int(evaluations),
            "seconds": time.perf_counter() - t0}


def grid_points(spec: DesignSpec, per_side: int) -> np.ndarray:
    """Lattice of ``per_side`` x ``per_side`` points spanning the footprint's bounding square
    (edges included), restricted to the footprint: (M, 2) metres."""
    h = spec.half_size
    g = np.linspace(-h, h, per_side)
    pts = np.stack(np.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)
    if spec.shape == "disc":
        pts = pts[np.linalg.norm(pts, axis=-1) <= h + 1e-12]
    return pts


def grid_search(spec: DesignSpec, evaluations: int, batch: int = 8,
                dtype=jnp.float32) -> dict:
    """Exhaustive search over camera placements on a lattice, within an evaluation budget.

    Every camera sits on a point of the coarsest ``g x g`` lattice (edges included) whose
    number of placements of the cameras on distinct points, ``C(M, N)``, reaches the budget;
    when it exceeds it, placements evenly spaced in enumeration order (lexicographic in the
    point indices) are taken up to the budget. They are evaluated with the cameras looking
    along +z at z = 0 (the grid does not search orientations or heights: their dimension
    would leave at most a handful of values per axis). Returns the keys of
    :func:`random_search` plus ``per_side`` and ``points``.
    """
    t0 = time.perf_counter()
    n = spec.num_cameras
    g = 2
    while len(grid_points(spec, g)) < n:
        g += 1
    while math.comb(len(grid_points(spec, g)), n) < evaluations:
        g += 1
    pts = grid_points(spec, g)
    combos = np.asarray(list(itertools.combinations(range(len(pts)), n)))
    if len(combos) > evaluations:
        # The lattice has more placements than the budget: evenly spaced ones in
        # enumeration order, so that the budget is used in full.
        combos = combos[np.unique(np.linspace(0, len(combos) - 1, evaluations).round()
                                  .astype(int))]
    lays = Layout(jnp.asarray(pts[combos], dtype), jnp.zeros((len(combos), n), dtype),
                  jnp.zeros((len(combos), n, 3), dtype))
    vals = evaluate_layouts(lays, spec, batch)["total"]
    i = int(np.nanargmin(vals))
    return {"best": index_layout(lays, i), "values": vals,
            "best_so_far": np.minimum.accumulate(vals), "evaluations": int(len(combos)),
            "seconds": time.perf_counter() - t0, "per_side": g, "points": int(len(pts))}
