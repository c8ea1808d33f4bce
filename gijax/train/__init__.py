"""Training: losses, the data-parallel trainer and checkpoints under a run folder (the metrics
it validates with live in :mod:`gijax.evaluate`)."""

from gijax.train.config import TrainConfig, load_run_config
from gijax.train.losses import smooth_l1_loss, two_hot_target, volume_loss

__all__ = ["TrainConfig", "load_run_config", "smooth_l1_loss", "two_hot_target", "volume_loss"]
