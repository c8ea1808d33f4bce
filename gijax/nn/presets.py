"""Model configurations by name: the paper's variants at their published size and CPU-scale twins.

Paper size (REFERENCE section 4): 512 x 2048 surrogate images per camera, features at stride 4
(128 x 512, 16 channels), an 80 x 320 cost volume over the rig hemisphere, a 160 x 640 output.

=============  ==========  ======  =========  ===========  ===========  =======================
name           candidates  loss    features   cost volume  U-Net        parameters (REFERENCE)
=============  ==========  ======  =========  ===========  ===========  =======================
E8 / G8        8 EV / GI   L1      plain      concat 48    in48 / f96   36.7 M
E16 / G16      16 EV / GI  L1      plain      concat 48    in48 / f96   36.7 M
G16V           16 GI       volume  plain      concat 48    in48 / f96   36.7 M (as in the paper)
G16V-released  16 GI       volume  plain      variance 16  in16 / f32   4.15 M (released ONNX)
G16VV          16 GI       volume  spherical  variance 16  in16 / f96   36.5 M
=============  ==========  ======  =========  ===========  ===========  =======================

CPU-scale designs of gijax's own (options off in the paper presets): ``G16VV-cpu-fine`` (the cost
volume at the output's 32 x 128, ``output_stride=1``), ``G32VV-cpu`` (32 candidates),
``G16VV-cpu-refine`` (a guided refinement at the output's resolution, ``refine=True``),
``G16VV-cpu-zncc`` (the classical matching cost as a cost-volume channel,
``matching_cost='zncc'``) and ``G16VV-cpu-wide`` (16 feature channels in 2 residual blocks at the
feature resolution).

The ``-cpu`` presets keep every structural choice (candidate count and kind, loss, feature kind,
cost-volume kind, camera count, mask augmentation) and shrink the sizes so that a model trains on
a laptop CPU in minutes: raw fisheye images scaled by 0.25, 128 x 512 surrogates, 32 x 128
features with 8 channels and (2, 3) residual blocks, a 16 x 64 cost volume, a 32 x 128 output.
"""

from __future__ import annotations

import dataclasses

from gijax.checks import bad_field
from gijax.nn.layers import CONV3D_LOWERINGS
from gijax.nn.regressor import ESTIMATES

_CANDIDATE_KINDS = ("ev", "gi")
_LOSSES = ("smooth_l1", "volume")
_FEATURES = ("plain", "spherical")
_COST_VOLUMES = ("concat", "variance")
_SPHERICAL_TAPS = ("release", "tangent")
_SWEEP_BOUNDARIES = ("zeros", "wrap")
MATCHING_COSTS = ("none", "zncc")
PANORAMA_COVERAGES = ("hemisphere", "sphere")
OUTPUT_STRIDES = (1, 2)


# Network configuration fields that change what a network is applied to or trained for, not any
# weight: a model trained at one resolution, coverage, input scale, loss or estimate starts a run
# at another (G16VV-cpu -> G16VV-cpu-fine; a hemisphere model fine-tuned on a full-sphere rig; a
# small rig's images at full size; a volume-loss model fine-tuned on the smooth L1 of its
# estimate, read by the mean or by the sub-pixel mode; a 16-candidate network fine-tuned at 32:
# the cost volume's candidate axis is convolved, never a weight's size). The variable shapes are
# still checked one by one after the configuration.
WEIGHTLESS_FIELDS = frozenset({"name", "conv3d", "cost_hw", "output_hw", "output_stride",
                               "panorama", "image_scale", "loss", "estimate", "mode_window",
                               "mode_pick", "num_candidates"})
# Fields that add parameters starting as the identity (a zero-initialised path added to the
# logits), with the value that leaves them out: a trained network without them initialises one
# with them (``gijax train --init-from``), whose outputs are then the same until it trains.
GROWN_FIELDS = {"matching_skip": False}


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """Everything that fixes a network's structure and sizes (hashable, usable as a jit static).

    Sizes are (height, width) in pixels. ``surrogate_hw`` is the per-camera hemisphere image fed
    to the feature extractor (features come out at a quarter of it), ``cost_hw`` the grid of
    the cost volume over the rig panorama and ``output_hw`` the regressed panorama (twice
    ``cost_hw``). ``panorama`` is the part of the sphere those two cover and the model is
    trained on: ``'hemisphere'`` (the paper's, around the panorama pole) or ``'sphere'``; a
    model runs on the other coverage at the same angular resolution
    (:func:`gijax.model.model_panorama`). ``image_scale`` is the factor applied to the raw fisheye images and the rig
    intrinsics before resampling (1.0 at paper size). Distances ``d_min``/``d_max`` are metres.
    ``unet_in`` is the number of channels of the cost volume, which the U-Net consumes: the
    camera count times ``feature_channels`` for concat; for variance the width the cost
    volume's conv maps the feature channels to (``feature_channels`` in the paper's presets).
    ``output_stride`` is ``output_hw / cost_hw``: 2 in the paper (the logits are upsampled x2
    before the softmax); 1 puts the cost volume at the output's resolution (gijax's finer
    CPU-scale design, ``G16VV-cpu-fine``: a cell per feature pixel, sharper depth edges).
    ``refine`` adds gijax's guided refinement after the soft-argmax (:mod:`gijax.nn.refine`:
    a small 2-D network at the output's resolution, guided by the cameras' colours at the
    estimated distance; ``G16VV-cpu-refine``). ``matching_cost = 'zncc'`` adds the classical
    matching cost as one more channel of the cost volume, beside the learned features
    (:mod:`gijax.sweep.matching`: per candidate and cell, the mean zero-mean normalised
    cross-correlation of the cameras' grey levels at ``matching_samples x matching_samples``
    sub-cell points, read from the surrogate images; ``G16VV-cpu-zncc``); ``'none'`` (the
    paper's) leaves it out. ``matching_skip`` (with a matching cost only) also adds that cost
    to the U-Net's logits through a zero-initialised 3x3x3 conv (:mod:`gijax.nn.matching_skip`:
    a path at the cost's own resolution, for structures the U-Net's coarse stages smooth away).
    ``estimate`` is how the distance is read from the probabilities over the candidates
    (:mod:`gijax.nn.regressor`): ``'mean'`` (the paper's soft-argmax) or ``'mode'``, the
    expectation within ``mode_window`` candidates of the most probable one (the sub-pixel
    mode: a pixel on an occlusion boundary takes one surface instead of a distance between
    two), the most probable one being the candidate with the most probability within
    ``mode_pick`` candidates on each side (0: the single most probable candidate, Tulyakov's
    rule; 1 keeps a surface that lies between two candidates from losing to a narrower false
    match); none of them changes a weight, and the volume loss does not depend on them.

    Two choices keep the release's behaviour by default and offer gijax's alternative:

    * ``spherical_taps`` (spherical features only): ``'release'``, the taps the released G16VV
      was trained with, or ``'tangent'``, the tangent-plane kernel the paper describes (see
      :mod:`gijax.nn.spherical`);
    * ``sweep_boundary``: how the sweep samples feature maps and masks near their edges:
      ``'zeros'``, the release's ``grid_sample`` zero padding, or ``'wrap'``, longitude wrapping
      across the seam (see :mod:`gijax.sweep.sample`).

    ``conv3d`` chooses how the 3-D convolutions (cost volume and U-Net) lower to XLA; it changes
    neither the parameters nor the results (up to float rounding), so weights move freely
    between lowerings (see :class:`gijax.nn.layers.Conv3D`):

    * ``'split'``: 2-D convolutions over depth slices, 4-10x faster than XLA's CPU 3-D conv;
    * ``'native'``: one 3-D convolution, for GPUs and for ONNX export (one Conv node each);
    * ``'auto'`` (default): 'split' when compiling for the CPU backend, 'native' otherwise.
    """

    name: str
    num_candidates: int
    candidates: str
    loss: str
    features: str
    cost_volume: str
    num_cameras: int = 3
    feature_channels: int = 16
    feature_blocks: tuple[int, int] = (5, 10)
    unet_in: int = 48
    unet_base: int = 96
    surrogate_hw: tuple[int, int] = (512, 2048)
    cost_hw: tuple[int, int] = (80, 320)
    output_hw: tuple[int, int] = (160, 640)
    image_scale: float = 1.0
    mask_augmentation: bool = False
    d_min: float = 0.5
    d_max: float = 100.0
    spherical_taps: str = "release"
    sweep_boundary: str = "zeros"
    conv3d: str = "auto"
    panorama: str = "hemisphere"
    output_stride: int = 2
    refine: bool = False
    matching_cost: str = "none"
    matching_samples: int = 4
    estimate: str = "mean"
    mode_window: int = 2
    matching_skip: bool = False
    mode_pick: int = 0

    def __post_init__(self) -> None:
        def fail(field: str, expected: str, found) -> None:
            raise bad_field(f"ModelConfig {self.name!r}", field, expected, found)

        for field, allowed in (
            ("candidates", _CANDIDATE_KINDS),
            ("loss", _LOSSES),
            ("features", _FEATURES),
            ("cost_volume", _COST_VOLUMES),
            ("spherical_taps", _SPHERICAL_TAPS),
            ("sweep_boundary", _SWEEP_BOUNDARIES),
            ("conv3d", CONV3D_LOWERINGS),
            ("panorama", PANORAMA_COVERAGES),
            ("matching_cost", MATCHING_COSTS),
            ("estimate", ESTIMATES),
        ):
            if getattr(self, field) not in allowed:
                fail(field, f"one of {allowed}", getattr(self, field))
        # The U-Net halves the candidate axis and both spatial axes three times.
        if self.num_candidates < 8 or self.num_candidates % 8:
            fail("num_candidates", "a positive multiple of 8 (the U-Net halves it 3 times)",
                 self.num_candidates)
        for field in ("cost_hw", "surrogate_hw", "output_hw"):
            hw = getattr(self, field)
            if len(hw) != 2 or any(int(s) != s or s <= 0 for s in hw):
                fail(field, "two positive integers (height, width)", hw)
        if any(s % 8 for s in self.cost_hw):
            fail("cost_hw", "both sides divisible by 8 (the U-Net halves them 3 times)",
                 self.cost_hw)
        if any(s % 4 for s in self.surrogate_hw):
            fail("surrogate_hw", "both sides divisible by 4 (features are at stride 4)",
                 self.surrogate_hw)
        if self.output_stride not in OUTPUT_STRIDES:
            fail("output_stride", f"one of {OUTPUT_STRIDES}", self.output_stride)
        k = self.output_stride
        if tuple(self.output_hw) != (k * self.cost_hw[0], k * self.cost_hw[1]):
            fail("output_hw", f"output_stride x cost_hw = {(k * self.cost_hw[0], k * self.cost_hw[1])}",
                 self.output_hw)
        if len(self.feature_blocks) != 2 or any(b < 0 for b in self.feature_blocks):
            fail("feature_blocks", "two non-negative block counts", self.feature_blocks)
        for field in ("num_cameras", "feature_channels", "unet_base", "matching_samples"):
            if getattr(self, field) < 1:
                fail(field, "a positive integer", getattr(self, field))
        # A concat volume's conv sees the stacked cameras; a variance volume's conv maps the
        # feature channels to any width (the paper's presets keep the two equal).
        if self.cost_volume == "concat" and self.unet_in != self.num_cameras * self.feature_channels:
            fail("unet_in", f"{self.num_cameras * self.feature_channels} for a concat cost volume",
                 self.unet_in)
        if self.unet_in < 1:
            fail("unet_in", "a positive integer", self.unet_in)
        if self.cost_volume == "variance" and self.num_cameras < 2:
            fail("num_cameras", "at least 2 for a variance cost volume", self.num_cameras)
        if not 0.0 < self.d_min < self.d_max:
            fail("d_min/d_max", "0 < d_min < d_max", (self.d_min, self.d_max))
        if not self.image_scale > 0:
            fail("image_scale", "a positive factor", self.image_scale)
        if self.matching_skip not in (False, True):
            fail("matching_skip", "true or false", self.matching_skip)
        if self.matching_skip and self.matching_cost == "none":
            fail("matching_skip", "false for a model without a matching cost (matching_cost "
                 "'none')", self.matching_skip)
        if self.mode_window < 0:
            fail("mode_window", "a non-negative number of candidates", self.mode_window)
        if self.mode_pick < 0:
            fail("mode_pick", "a non-negative number of candidates", self.mode_pick)

    @property
    def feature_hw(self) -> tuple[int, int]:
        """(height, width) of the feature maps: a quarter of the surrogate image."""
        return (self.surrogate_hw[0] // 4, self.surrogate_hw[1] // 4)

    @property
    def cost_extra_channels(self) -> int:
        """Channels the cost-volume builder receives beside the fused features: 1 with the
        matching cost, else 0."""
        return 0 if self.matching_cost == "none" else 1

    @property
    def cost_volume_shape(self) -> tuple[int, int, int, int]:
        """(D, h, w, channels) of the cost volume of one sample."""
        return (self.num_candidates, *self.cost_hw, self.unet_in)


def _paper(name, n, cand, loss, features="plain", cost="concat", unet_base=96, mask_aug=False):
    unet_in = 48 if cost == "concat" else 16
    return ModelConfig(
        name=name, num_candidates=n, candidates=cand, loss=loss, features=features,
        cost_volume=cost, unet_in=unet_in, unet_base=unet_base, mask_augmentation=mask_aug,
    )


def _cpu(paper: ModelConfig, unet_base: int) -> ModelConfig:
    channels = 8
    unet_in = paper.num_cameras * channels if paper.cost_volume == "concat" else channels
    return dataclasses.replace(
        paper,
        name=paper.name + "-cpu",
        feature_channels=channels,
        feature_blocks=(2, 3),
        unet_in=unet_in,
        unet_base=unet_base,
        surrogate_hw=(128, 512),
        cost_hw=(16, 64),
        output_hw=(32, 128),
        image_scale=0.25,
    )


_PAPER = [
    _paper("E8", 8, "ev", "smooth_l1"),
    _paper("G8", 8, "gi", "smooth_l1"),
    _paper("E16", 16, "ev", "smooth_l1"),
    _paper("G16", 16, "gi", "smooth_l1"),
    _paper("G16V", 16, "gi", "volume"),
    _paper("G16V-released", 16, "gi", "volume", cost="variance", unet_base=32, mask_aug=True),
    _paper("G16VV", 16, "gi", "volume", features="spherical", cost="variance", unet_base=96,
           mask_aug=True),
]

# CPU U-Net widths keep the paper's ordering: the in16/f32 released variance model is the
# narrowest, G16VV's U-Net is wider than its input, concat models get the camera-stacked input.
_CPU_BASE = {"G16V-released": 12, "G16VV": 16}

PRESETS: dict[str, ModelConfig] = {c.name: c for c in _PAPER}
PRESETS.update({c.name + "-cpu": _cpu(c, _CPU_BASE.get(c.name, 16)) for c in _PAPER})

# gijax's CPU-scale designs, compared at an equal training budget by
# experiments/design_comparison.py (not the paper's; every new part is an option that the paper
# presets leave off). The G16VV-cpu cost volume has a cell per 2 x 2 output pixels (5.6 degrees
# of the hemisphere's width): -fine puts it at the output's resolution, a cell per feature
# pixel, with the same weights (the cost-volume conv and U-Net are fully convolutional).
_G16VV_CPU = PRESETS["G16VV-cpu"]
_DESIGNS = [
    dataclasses.replace(_G16VV_CPU, name="G16VV-cpu-fine", cost_hw=(32, 128), output_stride=1),
    dataclasses.replace(_G16VV_CPU, name="G32VV-cpu", num_candidates=32),
    dataclasses.replace(_G16VV_CPU, name="G16VV-cpu-refine", refine=True),
    # The classical cue beside the learned one: ZNCC of 4 x 4 colour samples per cell.
    dataclasses.replace(_G16VV_CPU, name="G16VV-cpu-zncc", matching_cost="zncc"),
    # Fewer, wider feature layers: 16 channels (a full AVX-512 vector, where 8 fill half of one)
    # in 2 residual blocks at the quarter resolution instead of 8 channels in 2 blocks at half
    # and 3 at quarter (about the same multiply-adds); the cost volume's conv maps them to the
    # U-Net's 8 input channels, so the U-Net is the bundle's.
    dataclasses.replace(_G16VV_CPU, name="G16VV-cpu-wide", feature_channels=16,
                        feature_blocks=(0, 2), unet_in=8),
]
PRESETS.update({c.name: c for c in _DESIGNS})

# Parameter counts of the paper-size networks as stated in REFERENCE section 4 (trainable
# parameters of feature extractor, cost-volume conv and U-Net).
REFERENCE_PARAM_COUNTS: dict[str, float] = {
    "E8": 36.7e6, "G8": 36.7e6, "E16": 36.7e6, "G16": 36.7e6, "G16V": 36.7e6,
    "G16V-released": 4.15e6, "G16VV": 36.5e6,
}


def get_preset(name: str) -> ModelConfig:
    """The :class:`ModelConfig` called ``name`` (e.g. 'G16VV', 'G8-cpu')."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(
            f"unknown model preset {name!r}; valid names: {', '.join(PRESETS)}"
        ) from None
