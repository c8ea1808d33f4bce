"""What the exported graph is built from, besides the network itself.

The exported function is the network on raw fisheye images (their surrogate images by
:func:`gijax.sweep.grids.fisheye_surrogates`, then ``model(surrogates, masks, grids)``), with
the :class:`gijax.sweep.grids.SurrogateMaps` and the sweep grids of
:func:`gijax.model.model_grids` either evaluated once, eagerly, and baked into the file as
constants (a fixed rig: the engine only gathers), or computed inside the exported function
from rig inputs. This module holds the second case's pieces: the rig as plain arrays and back.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gijax.geometry.rig import Rig, is_homogeneous

Array = jax.Array


# ----------------------------------------------------------------------------- rig as inputs

def intrinsics_layout(rig: Rig) -> tuple[str, ...]:
    """Column names of the (N, P) intrinsics input: the model's parameters, then ``fov``
    (radians). ValueError when the cameras do not share one model and image size."""
    if not is_homogeneous(rig) and len({type(c) for c in rig.cameras}) != 1:
        models = sorted({c.MODEL for c in rig.cameras})
        raise ValueError(f"a rig exported with its intrinsics as inputs needs one camera model "
                         f"for all cameras; this rig mixes {models}")
    sizes = {(c.width, c.height) for c in rig.cameras}
    if len(sizes) != 1:
        raise ValueError(f"a rig exported with its intrinsics as inputs needs one image size for "
                         f"all cameras; found {sorted(sizes)} (width, height)")
    return (*rig.cameras[0].PARAMS, "fov")


def rig_arrays(rig: Rig) -> dict:
    """The rig as plain arrays: ``intrinsics`` (N, P) float32 in the order of
    :func:`intrinsics_layout`, ``rotations`` (N, 3, 3), ``translations`` (N, 3) metres,
    ``reference`` (3,) metres."""
    names = intrinsics_layout(rig)
    intr = jnp.stack([jnp.stack([jnp.asarray(getattr(c, k), jnp.float32) for k in names])
                      for c in rig.cameras])
    return {"intrinsics": intr, "rotations": jnp.asarray(rig.rotations, jnp.float32),
            "translations": jnp.asarray(rig.translations, jnp.float32),
            "reference": jnp.asarray(rig.reference, jnp.float32)}


def rig_from_arrays(template: Rig, intrinsics: Array, rotations: Array, translations: Array,
                    reference: Array) -> Rig:
    """``template`` with its intrinsics, poses and reference replaced (camera model, image size
    and names stay those of the template); traceable."""
    names = intrinsics_layout(template)
    cams = []
    for i, cam in enumerate(template.cameras):
        values = {k: intrinsics[i, j] for j, k in enumerate(names)}
        cams.append(dataclasses.replace(cam, **values))
    return template.replace(cameras=tuple(cams), rotations=rotations, translations=translations,
                            reference=reference, masks=tuple(None for _ in cams), occluder=None)
