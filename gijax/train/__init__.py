"""Training: losses, metrics, the data-parallel trainer and checkpoints under a run folder."""

from gijax.train.config import TrainConfig, load_run_config
from gijax.train.losses import smooth_l1_loss, two_hot_target, volume_loss
from gijax.train.metrics import evaluate_batch, ssim_map

__all__ = ["TrainConfig", "load_run_config", "smooth_l1_loss", "two_hot_target", "volume_loss",
           "evaluate_batch", "ssim_map"]
