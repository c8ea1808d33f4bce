"""Constant-time graph lookups for jax2onnx's converter, used while :func:`export_onnx` runs.

jax2onnx 0.17 answers two questions by scanning the whole graph built so far:

* ``output_binding._value_is_graph_connected(ctx, value)``: after every lowered equation, is
  each output a graph input, an initializer or the output of a node in the graph? It compares
  the value with every node's every output, so a conversion of E equations costs O(E^2);
* ``optimizer_graph_utils._producer_node(nodes, value)``: the node among ``nodes`` that produces
  ``value``. It builds a set of every node's id before each lookup, again O(nodes) per call, in
  optimisation passes that look up producers of most values.

Together they took 40-70 % of an export's time (``benchmarks/bench_export.py``: exports
1.7-3.1x faster without them, CPU and paper-size presets alike). Both can be answered from the
value itself: an ONNX-IR value knows its producer, and a node knows the graph it is in (ONNX-IR
keeps ``node.graph`` equal to the graph that holds it, setting and clearing it as nodes are
added and removed). :func:`fast_lookups` patches both functions,
for the duration of a ``with`` block, with versions that return at once when the answer is that
producer and otherwise call the original; a fast answer is always the answer the original
gives (see each function), so the exported file is unchanged byte for byte
(tests/test_export.py checks it against the unpatched converter).

The patch is applied only where the functions are the ones it was written for (jax2onnx's
module names and signatures of the 0.17 series, pinned in pyproject.toml); elsewhere it leaves
the converter as it is.
"""

from __future__ import annotations

import contextlib
import importlib
import inspect

# Modules that hold a reference to ``_producer_node`` (imported by name, so each is patched).
_PRODUCER_HOLDERS = ("jax2onnx.converter.optimizer_graph_utils",
                     "jax2onnx.converter.ir_optimizations",
                     "jax2onnx.converter.conv_transpose_bias_folding")
_CONNECTED_HOLDER = "jax2onnx.converter.output_binding"


def _connected_fast(original):
    import onnx_ir as ir

    def value_is_graph_connected(ctx, value):
        # The original returns True when some node of the graph has ``value`` among its outputs
        # (compared by identity first); a producer that is in the graph and lists the value is
        # such a node.
        producer = value.producer() if isinstance(value, ir.Value) else None
        if (producer is not None and producer.graph is ctx.builder.nodes
                and any(out is value for out in producer.outputs)):
            return True
        return original(ctx, value)

    value_is_graph_connected.__wrapped__ = original
    return value_is_graph_connected


def _producer_fast(original):
    import onnx_ir as ir

    def producer_node(nodes, value_or_name):
        # The original's first answer: the value's own producer when it is one of ``nodes``
        # (by identity; ONNX-IR nodes compare by identity, so ``in`` on a list is that test at
        # C speed instead of a set of every node's id built per call).
        if isinstance(value_or_name, ir.Value) and isinstance(nodes, (list, tuple)):
            producer = value_or_name.producer()
            if isinstance(producer, ir.Node) and producer in nodes:
                return producer
        return original(nodes, value_or_name)

    producer_node.__wrapped__ = original
    return producer_node


def _patch_targets():
    """``[(module, attribute, replacement)]``, or ``[]`` when jax2onnx's internals are not the
    ones this module was written for."""
    try:
        connected_mod = importlib.import_module(_CONNECTED_HOLDER)
        producer_mods = [importlib.import_module(name) for name in _PRODUCER_HOLDERS]
        connected = connected_mod._value_is_graph_connected
        producer = producer_mods[0]._producer_node
    except (ImportError, AttributeError):
        return []
    if (list(inspect.signature(connected).parameters) != ["ctx", "value"]
            or list(inspect.signature(producer).parameters) != ["nodes", "value_or_name"]
            or any(getattr(m, "_producer_node", None) is not producer for m in producer_mods)):
        return []
    targets = [(connected_mod, "_value_is_graph_connected", _connected_fast(connected))]
    fast_producer = _producer_fast(producer)
    targets += [(m, "_producer_node", fast_producer) for m in producer_mods]
    return targets


@contextlib.contextmanager
def fast_lookups():
    """Within the block, jax2onnx's graph lookups answer in constant time where they can (see
    the module docstring); the originals are restored on leaving it, also on an error."""
    targets = _patch_targets()
    saved = [(module, name, getattr(module, name)) for module, name, _ in targets]
    try:
        for module, name, replacement in targets:
            setattr(module, name, replacement)
        yield bool(targets)
    finally:
        for module, name, original in saved:
            setattr(module, name, original)
