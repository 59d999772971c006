"""The models fftool ships and the profiles they were trained with: `fftool` finds `models/` here when it runs
from an installed wheel (`fftool.zoo.models_root`); every file is still checked against its manifest's hash."""

from pathlib import Path

MODELS = Path(__file__).parent / "models"
