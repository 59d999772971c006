"""fftool: ForceFormer pedestrian-trajectory prediction, reproducible and fast."""

__version__ = "0.1.0"
