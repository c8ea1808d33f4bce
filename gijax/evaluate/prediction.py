"""What every method's prediction is, and what a predictor offers.

:class:`Prediction` is the one result type of the learned model (JAX), the classical RTSS
baseline and an exported model run by onnxruntime: panoramas of inverse distance, distance and
validity, plus what a method has beyond them (the learned model's candidate distribution and
its entropy, the colour of each predicted point). Fields a method does not produce are None and
absent when the prediction is read as a mapping (``"entropy" in prediction`` is False for the
baseline), so code that writes files asks the prediction what it holds.

A :class:`Predictor` turns the raw fisheye images of one sample into a :class:`Prediction`:
the learned model (:class:`gijax.predict.LearnedPredictor`), the baseline
(:class:`gijax.predict.RtssPredictor`) and an ONNX file
(:class:`gijax.export.ort_predict.OnnxPredictor`) all offer the same ``predict`` call.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, Callable, Optional, Protocol, runtime_checkable


@dataclasses.dataclass(frozen=True, eq=False)
class Prediction(Mapping):
    """One method's panoramas, for one sample (H, W) or a batch (B, H, W).

    ``inv_distance`` 1/m and ``valid`` (bool: the method gave an estimate there) always;
    ``distance`` metres; ``entropy`` nats and ``prob`` (D, H, W) of the candidate distribution
    (learned models only); ``colour`` (H, W, 3) in [0, 1], the image colour at each predicted
    point; ``rgb`` (kH, kW, 3) and ``rgb_valid`` the colour panorama at the resolution the
    cameras support (k >= 1; None where a method does not make one: ``colour`` serves then);
    ``candidates`` (D,) metres; ``panorama`` the
    :class:`~gijax.geometry.panorama.Panorama` of the maps. Read by attribute or by key.
    """

    inv_distance: Any
    valid: Any
    distance: Any = None
    entropy: Any = None
    prob: Any = None
    colour: Any = None
    rgb: Any = None
    rgb_valid: Any = None
    candidates: Any = None
    panorama: Any = None

    def __getitem__(self, key: str):
        value = getattr(self, key, None) if key in _FIELDS else None
        if value is None:
            raise KeyError(key)
        return value

    def __iter__(self):
        return (f for f in _FIELDS if getattr(self, f) is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def replace(self, **changes) -> "Prediction":
        return dataclasses.replace(self, **changes)


_FIELDS = tuple(f.name for f in dataclasses.fields(Prediction))


@runtime_checkable
class Predictor(Protocol):
    """Raw fisheye images of one sample -> :class:`Prediction`.

    ``rig`` the rig the images come from; ``images`` (N, h, w, 3) uint8 or float RGB in [0, 1];
    ``masks`` (N, h, w) or None for the rig's own; ``log`` receives notes (a resize, a
    panorama the model was not trained on).
    """

    def predict(self, rig, images, masks=None, log: Optional[Callable[[str], None]] = None
                ) -> Prediction:
        ...
