"""Shared test fixtures. float64 is enabled per test with ``jax.enable_x64`` where needed."""

import os

# XLA's CPU compiler spends about half of each compilation in its MLIR fusion emitters; the
# suite compiles thousands of programs (every eager op of a new shape is one), so it compiles
# with the classic emitters instead: about 2x faster to compile, same numerics within the
# tests' tolerances. Set before JAX starts its CPU backend; subprocess tests inherit it.
# GIJAX_TEST_XLA_DEFAULTS=1 runs the suite with XLA's default emitters.
if os.environ.get("GIJAX_TEST_XLA_DEFAULTS") != "1":
    _FLAG = "--xla_cpu_use_fusion_emitters=false"
    if _FLAG not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _FLAG).strip()

# One persistent compilation cache per test process, shared with every subprocess it starts
# (they inherit the environment): files compile the same programs again (a tiny network's
# training step, the CLI's predictors and exports, the experiments' smoke runs), and each is
# compiled once per worker. Per process, not per run: JAX writes an entry in place, so a second
# xdist worker could read one half-written, and its warning would reach the stderr that tests
# read. Only programs that take a while to compile are stored; the thousands of small eager ops
# would cost more to write than to compile. The process that made a folder removes it.
# GIJAX_TEST_COMPILE_CACHE=0 turns it off; a JAX_COMPILATION_CACHE_DIR set by the caller is used
# as it is and never removed.
_OWN_CACHE_VAR = "GIJAX_TEST_OWN_COMPILE_CACHE"      # "<pid>:<folder>" of the folder's maker
if os.environ.get("GIJAX_TEST_COMPILE_CACHE") != "0" and (
        "JAX_COMPILATION_CACHE_DIR" not in os.environ
        or os.environ.get(_OWN_CACHE_VAR, "").split(":", 1)[0] not in ("", str(os.getpid()))):
    import tempfile

    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="gijax-test-xla-cache-")
    os.environ[_OWN_CACHE_VAR] = f"{os.getpid()}:{os.environ['JAX_COMPILATION_CACHE_DIR']}"
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")

import jax  # noqa: E402
import pytest  # noqa: E402

if os.environ.get(_OWN_CACHE_VAR, "").startswith(f"{os.getpid()}:"):
    # In case a plugin imported JAX before this file set its environment.
    jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
    jax.config.update("jax_persistent_cache_min_compile_time_secs",
                      float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]))


def pytest_unconfigure(config):
    """The process that made a compilation cache folder (above) removes it."""
    pid, _, folder = os.environ.get(_OWN_CACHE_VAR, "").partition(":")
    if pid == str(os.getpid()) and folder == os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        import shutil

        shutil.rmtree(folder, ignore_errors=True)


# The longest library test files (summed test seconds on 2 cores with a fresh compile cache,
# measured), in decreasing order. Under ``--dist loadfile`` (pyproject.toml) files go to the
# workers in collection order, so handing these out first keeps one worker from starting a long
# file when the other is nearly done.
LONGEST_FIRST = ("test_transforms", "test_train", "test_export", "test_calibrate", "test_model",
                 "test_nn", "test_train_parallel", "test_train_faults", "test_precision",
                 "test_network_adaptation", "test_rtss", "test_learned_candidates",
                 "test_reliability", "test_release_parity", "test_cameras", "test_faults",
                 "test_render", "test_panorama_frame", "test_matching", "test_design",
                 "test_evaluate", "test_candidates", "test_bundle", "test_augmentations",
                 "test_store", "test_predict_methods", "test_real_rig_edges", "test_lens_draw")
# The end-to-end runs come after every library test: they run the library through the
# experiment scripts, the tutorial notebook and the demo, so a library defect is reported by
# its own test first. The experiments' smoke runs (the longest file) are handed out first, so
# the other worker runs the tutorial and the demo beside them instead of waiting.
LAST = ("test_experiments", "test_tutorial", "test_demo")


def pytest_collection_modifyitems(config, items):
    """Longest library files first (see :data:`LONGEST_FIRST`; the order inside a file is
    kept), the experiments' smoke runs last (:data:`LAST`), and tests marked ``long`` (extra
    seeds of the fault probe) run only with GIJAX_LONG_TESTS=1, so the default suite stays
    within its time budget."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    rank.update({name: len(LONGEST_FIRST) + 1 + i for i, name in enumerate(LAST)})

    def file_rank(item):
        return rank.get(item.path.stem, len(LONGEST_FIRST))

    items[:] = sorted(items, key=file_rank)   # stable: collection order within a rank
    if os.environ.get("GIJAX_LONG_TESTS") == "1":
        return
    skip = pytest.mark.skip(reason="long variant: set GIJAX_LONG_TESTS=1 to run it")
    for item in items:
        if "long" in item.keywords:
            item.add_marker(skip)


def persistent_compile_cache(folder):
    """Generator for a fixture: JAX's persistent compilation cache in ``folder`` with every
    program cached (the training tests and their subprocesses share one folder, so a training
    step compiles once), the previous settings restored afterwards. With the same size limit as
    the subprocesses (``test_train_faults.child_env``): a limit makes JAX write each entry's
    access-time file, which a subprocess's eviction reads for every entry in the folder, so an
    entry written here without one would make every write there fail with a warning on its
    stderr."""
    names = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
             "jax_persistent_cache_min_entry_size_bytes", "jax_compilation_cache_max_size")
    old = [getattr(jax.config, n) for n in names]
    for name, value in zip(names, (str(folder), 0.0, 0, 8 << 30)):
        jax.config.update(name, value)
    yield
    for name, value in zip(names, old):
        jax.config.update(name, value)


def _without_optimisations():
    previous = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", True)
    yield
    jax.config.update("jax_disable_most_optimizations", previous)
    # JAX's in-memory caches do not key on this setting: an eager op or a jitted function
    # compiled without the passes here would be reused, unoptimised, by later modules whose
    # checks compare optimised programs to within a few float32 ulps. (The persistent cache
    # keys on the compile options, so its entries stay apart.)
    jax.clear_caches()


@pytest.fixture(scope="module")
def quick_compiles():
    """Compile without XLA's optimisation passes, for modules whose checks (shapes,
    invariances, gradients, errors, files) do not depend on them: they dominate compile time.

    Not for checks of a gradient-accumulation step: unoptimised, XLA CPU reports a wrong loss
    for it (tests/test_train.py keeps that test optimised)."""
    yield from _without_optimisations()


@pytest.fixture
def quick_compiles_here():
    """:func:`quick_compiles` for one test of a module whose other tests keep the passes."""
    yield from _without_optimisations()
