"""Evaluation and prediction results: usable labels, the metrics, the one result type of every
method and the loop that scores a predictor over a dataset.

Pure functions on arrays (:mod:`~gijax.evaluate.labels`, :mod:`~gijax.evaluate.metrics`) and
the host-side loop (:mod:`~gijax.evaluate.loop`); the predictors themselves live with their
methods (:mod:`gijax.predict`, :mod:`gijax.export.ort_predict`).
"""

from gijax.evaluate.labels import clamped_inverse, label_mask, usable_label
from gijax.evaluate.loop import HOLES, Evaluation, evaluate_predictions
from gijax.evaluate.metrics import (METRIC_SETS, batch_sums, evaluate_batch, ssim_map,
                                    summarize)
from gijax.evaluate.prediction import Prediction, Predictor

__all__ = ["clamped_inverse", "label_mask", "usable_label", "HOLES", "Evaluation",
           "evaluate_predictions", "METRIC_SETS", "batch_sums", "evaluate_batch", "ssim_map",
           "summarize", "Prediction", "Predictor"]
