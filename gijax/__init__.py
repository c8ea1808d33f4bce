"""gijax: geometry-informed distance candidates for omnidirectional fisheye stereo, in JAX."""

__version__ = "0.1.0"
