"""The jitted training and evaluation steps, and their data-parallel placement.

The training state is a plain pytree (dict) so that it can be jitted, sharded and checkpointed
as is:

* ``params``: the model's ``nnx.Param`` variables (an ``nnx.State``);
* ``rest``: every other model variable (BatchNorm running statistics, RNG streams);
* ``opt``: the optax optimiser state;
* ``step``: int32 scalar, optimiser updates done;
* with a learned candidate list (``TrainConfig.learn_candidates``) also ``cand_logits``, the
  list's logits (:mod:`gijax.candidates.parametrisation`), and ``cand_opt``, their own Adam
  state.

Data parallelism: one mesh axis ``'data'`` over all devices of all processes. Batches are
sharded along their leading axis, the state is replicated; under ``jax.jit`` the gradient mean
over the batch becomes a cross-device reduction, and BatchNorm statistics are those of the
global batch, so a sharded step computes the same update as a single device would on the whole
batch.
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

from gijax.candidates.parametrisation import candidates_from_logits
from gijax.host_memory import release_freed_memory
from gijax.model import model_grids, model_panorama
from gijax.train.config import TrainConfig
from gijax.train.losses import model_loss
from gijax.train.unlabeled import TEACHER_KEYS, LabelFree, label_free_terms

Array = jax.Array
DATA_AXIS = "data"
BATCH_KEYS = ("surrogates", "masks", "distance", "valid")
# Arrays a batch may carry besides BATCH_KEYS, placed and split like them when present.
EXTRA_KEYS = TEACHER_KEYS


def learning_rate_schedule(cfg: TrainConfig) -> optax.Schedule:
    """The learning rate per step for ``cfg.schedule`` (see :class:`TrainConfig`)."""
    if cfg.schedule == "constant":
        return optax.constant_schedule(cfg.lr)
    if cfg.schedule == "cosine":
        return optax.cosine_decay_schedule(cfg.lr, max(cfg.steps, 1), alpha=cfg.end_lr_factor)
    if cfg.schedule == "warmup_cosine":
        return optax.warmup_cosine_decay_schedule(
            0.0, cfg.lr, max(cfg.warmup_steps, 1), max(cfg.steps, cfg.warmup_steps + 1),
            end_value=cfg.lr * cfg.end_lr_factor)
    return optax.exponential_decay(cfg.lr, cfg.decay_every, cfg.decay_factor, staircase=True)


def make_optimizer(cfg: TrainConfig) -> optax.GradientTransformation:
    """Adam on the configured schedule, after optional global-norm clipping."""
    adam = optax.adam(learning_rate_schedule(cfg))
    if cfg.clip_norm is None:
        return adam
    return optax.chain(optax.clip_by_global_norm(cfg.clip_norm), adam)


def split_model(model: nnx.Module):
    """(train graphdef, eval graphdef, params, rest) of a model (train/eval differ in BatchNorm).

    ``params`` holds the ``nnx.Param`` variables, ``rest`` every other variable (BatchNorm
    statistics, RNG streams), both as ``nnx.State`` pytrees.
    """
    model.eval()
    eval_def, _, _ = nnx.split(model, nnx.Param, ...)
    model.train()
    train_def, params, rest = nnx.split(model, nnx.Param, ...)
    return train_def, eval_def, params, rest


def load_into_model(model: nnx.Module, params, rest) -> nnx.Module:
    """Write trained variable states into ``model`` (in place) and return it."""
    nnx.update(model, params, rest)
    return model


def init_state(params, rest, tx: optax.GradientTransformation, cand_logits=None,
               tx_cand: optax.GradientTransformation | None = None) -> dict:
    state = {"params": params, "rest": rest, "opt": tx.init(params),
             "step": jnp.zeros((), jnp.int32)}
    if cand_logits is not None:
        logits = jnp.asarray(cand_logits, jnp.float32)
        state.update(cand_logits=logits, cand_opt=tx_cand.init(logits))
    return state


def state_candidates(state: dict, d_range) -> Array:
    """The learned list (N,) metres of a state with ``cand_logits`` (``d_range`` = its ends)."""
    return candidates_from_logits(state["cand_logits"], d_range[0], d_range[1])


def _cast_floats(tree, dtype):
    return jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x,
                        tree)


def build_train_step(graphdef, tx: optax.GradientTransformation, loss_kind: str,
                     grad_accum: int = 1, bf16: bool = False,
                     tx_cand: optax.GradientTransformation | None = None,
                     d_range=None, label_free: LabelFree | None = None) -> Callable:
    """``step(state, batch, rig, candidates) -> (state, {'loss', 'grad_norm'})`` (not jitted).

    With ``label_free`` the loss is that objective
    (:func:`gijax.train.unlabeled.label_free_terms`) on the refined inverse distance instead of
    ``loss_kind``'s label loss: the batch's ``distance`` and ``valid`` are then not read, and
    the info also holds each weighted term's value as ``loss_<term>``.

    With ``tx_cand`` the candidate list is learned: ``candidates`` is ignored, the list comes
    from ``state['cand_logits']`` (ends ``d_range``), and its logits are updated by ``tx_cand``
    from the gradient of the same loss, which reaches the list through the sweep grids and the
    soft-argmax (the label side of the loss, its clamping and two-hot target, is held at the
    current list: moving candidates must not move the target).

    ``batch`` holds ``surrogates`` (B, N, Hs, Ws, 3), ``masks`` (B, N, Hs, Ws), ``distance``
    (B, H, W) metres and ``valid`` (B, H, W). With ``grad_accum = k`` the batch is cut into k
    interleaved micro-batches (sample i goes to micro-batch i mod k, which keeps every
    micro-batch spread over all devices); their gradients are averaged and applied once.
    BatchNorm running statistics are updated by each micro-batch in turn. With ``bf16`` the
    forward and backward passes run in bfloat16; parameters, optimiser and loss stay float32.
    """
    learn = tx_cand is not None

    def forward(trainable, rest, batch, rig, candidates):
        if learn:
            params, logits = trainable
            candidates = candidates_from_logits(logits, d_range[0], d_range[1])
        else:
            params = trainable
        # Fresh Variable objects at this trace level: nnx only lets a module mutate variables
        # (BatchNorm statistics) created inside the transformation that runs it.
        rest = jax.tree.map(lambda x: x, rest)
        model = nnx.merge(graphdef, _cast_floats(params, jnp.bfloat16) if bf16 else params, rest)
        surrogates = batch["surrogates"].astype(jnp.bfloat16 if bf16 else jnp.float32)
        grids = model_grids(model.config, rig, candidates.astype(surrogates.dtype))
        out = model(surrogates, batch["masks"], grids)
        out = {k: v.astype(jnp.float32) if jnp.issubdtype(v.dtype, jnp.floating) else v
               for k, v in out.items()}
        if label_free is None:
            loss = model_loss(loss_kind, out, batch["distance"], batch["valid"],
                              jax.lax.stop_gradient(candidates))
            terms = {}
        else:
            terms = label_free_terms(label_free, out["inv_distance"], batch, rig,
                                     model_panorama(model.config))
            loss = terms.pop("loss")
        _, _, new_rest = nnx.split(model, nnx.Param, ...)
        return loss, (jax.tree.map(lambda new, old: new.astype(old.dtype), new_rest, rest),
                      terms)

    grad_fn = jax.value_and_grad(forward, has_aux=True)

    def step(state, batch, rig, candidates):
        params, rest = state["params"], state["rest"]
        trainable = (params, state["cand_logits"]) if learn else params
        if grad_accum == 1:
            (loss, (rest, terms)), grads = grad_fn(trainable, rest, batch, rig, candidates)
        else:
            def micro(x):
                m = x.shape[0] // grad_accum
                return x.reshape(m, grad_accum, *x.shape[1:]).swapaxes(0, 1)

            micro_batches = {k: micro(v) for k, v in batch.items()}

            def body(carry, mb):
                rest_c, g_sum, l_sum = carry
                (l, (rest_c, t)), g = grad_fn(trainable, rest_c, mb, rig, candidates)
                return (rest_c, jax.tree.map(jnp.add, g_sum, g), l_sum + l), t

            zeros = jax.tree.map(jnp.zeros_like, trainable)
            (rest, g_sum, l_sum), per_micro = jax.lax.scan(
                body, (rest, zeros, jnp.zeros(())), micro_batches)
            grads = jax.tree.map(lambda g: g / grad_accum, g_sum)
            loss = l_sum / grad_accum
            terms = {k: jnp.mean(v) for k, v in per_micro.items()}
        info = {"loss": loss, **{f"loss_{k}": v for k, v in terms.items()}}
        new_state = dict(state)
        if learn:
            grads, g_cand = grads
            logits = state["cand_logits"]
            upd, new_state["cand_opt"] = tx_cand.update(g_cand, state["cand_opt"], logits)
            new_state["cand_logits"] = optax.apply_updates(logits, upd)
            info["cand_grad_norm"] = optax.tree.norm(g_cand)
        updates, opt = tx.update(grads, state["opt"], params)
        params = optax.apply_updates(params, updates)
        new_state.update(params=params, rest=rest, opt=opt, step=state["step"] + 1)
        info["grad_norm"] = optax.tree.norm(grads)
        return new_state, info

    return step


def build_eval_forward(eval_graphdef) -> Callable:
    """``forward(params, rest, surrogates, masks, rig, candidates) -> model outputs`` in eval
    mode, the sweep grids made from ``rig`` inside."""

    def forward(params, rest, surrogates, masks, rig, candidates):
        model = nnx.merge(eval_graphdef, params, jax.tree.map(lambda x: x, rest))
        grids = model_grids(model.config, rig, jnp.asarray(candidates, surrogates.dtype))
        return model(surrogates, masks, grids)

    return forward


# --------------------------------------------------------------------------- placement

def make_mesh(devices=None) -> Mesh:
    """A 1-D mesh named 'data' over ``devices`` (default: every device of every process)."""
    devs = np.asarray(jax.devices() if devices is None else devices)
    return Mesh(devs.reshape(-1), (DATA_AXIS,))


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, P())


def batch_sharded(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, P(DATA_AXIS))


class CompiledAhead:
    """A jitted function that compiles each new input signature before its first run and
    then hands the heap memory the compiler freed back to the system.

    XLA's compiler frees a few hundred MB when it is done (about 0.5 GB for a CPU-scale
    training step), which glibc keeps in the process's heap; a compile inside the first call
    leaves it there and the step's buffers come on top of it. Compiled first and trimmed
    (:func:`gijax.host_memory.release_freed_memory`), a G16VV-cpu-zncc step at batch 8 peaked
    at 1.40 GB of resident memory instead of 1.88 GB. The call then runs the executable that
    ``lower(...).compile()`` put in JAX's cache; values do not change.
    """

    def __init__(self, jitted: Callable):
        self.jitted = jitted
        self._compiled_for: set = set()

    def __call__(self, *args):
        leaves, treedef = jax.tree_util.tree_flatten(args)
        # Attribute reads, not np.shape / str(dtype): this runs every step, on ~450 leaves.
        signature = (treedef, tuple((getattr(x, "shape", None), getattr(x, "dtype", type(x)))
                                    for x in leaves))
        if signature not in self._compiled_for:
            self.jitted.lower(*args).compile()
            release_freed_memory()
            self._compiled_for.add(signature)
        return self.jitted(*args)

    def lower(self, *args):
        return self.jitted.lower(*args)


def jit_train_step(step: Callable, mesh: Mesh) -> CompiledAhead:
    """Jit a train step with the state replicated and the batch sharded over 'data' (its state
    donated), compiled ahead of each new signature's first run (:class:`CompiledAhead`)."""
    rep, shard = replicated(mesh), batch_sharded(mesh)
    return CompiledAhead(jax.jit(step, in_shardings=(rep, shard, rep, rep),
                                 out_shardings=(rep, rep), donate_argnums=(0,)))


# How long the processes of a run wait for each other at a meeting point. Gloo gives up on its
# first collective after 30 s, and processes that import, build and compile at different
# speeds on a loaded machine drift further apart than that before their first collective.
MEETING_TIMEOUT_S = 600


def meet_all_processes(name: str) -> None:
    """Every process of a multi-process run waits here until all have arrived (the
    coordination service's barrier, :data:`MEETING_TIMEOUT_S`); a no-op in one process.
    Called before a run's first collective, so that the collective starts in step."""
    if jax.process_count() == 1:
        return
    from orbax.checkpoint.multihost import get_barrier_sync_fn

    get_barrier_sync_fn()(key=f"gijax-{name}", timeout_ms=MEETING_TIMEOUT_S * 1000)


def place_state(state: Any, mesh: Mesh) -> Any:
    """Replicate a host/single-device state over the mesh."""
    rep = replicated(mesh)
    if jax.process_count() == 1:
        return jax.device_put(state, rep)
    return jax.tree.map(
        lambda x: jax.make_array_from_process_local_data(rep, np.asarray(x)), state)


def place_batch(local_batch: dict, mesh: Mesh) -> dict:
    """This process's share of a batch (numpy) -> global arrays sharded over 'data'.

    Arrays that already have the step's dtype are placed without a copy, so the result may
    share memory with ``local_batch``: do not write into it while a step that uses it runs."""
    shard = batch_sharded(mesh)
    out = {}
    for k in BATCH_KEYS + tuple(k for k in EXTRA_KEYS if k in local_batch):
        # copy=False: a batch that already has the step's dtype is placed as it is (a float32
        # batch-8 CPU-scale batch is 19 MB; copying it took 40 ms of each step's host time).
        x = np.asarray(local_batch[k]).astype(bool if k == "valid" else np.float32, copy=False)
        gshape = (x.shape[0] * jax.process_count(),) + x.shape[1:]
        out[k] = jax.make_array_from_process_local_data(shard, x, gshape)
    return out


def abstract_like(state: Any, sharding) -> Any:
    """ShapeDtypeStructs of ``state`` with ``sharding`` (restore targets for orbax)."""
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), x.dtype, sharding=sharding),
                        state)
