"""Model files (SDF) and parameter files (YAML) shipped with alight."""
from pathlib import Path

MODELS_DIR = Path(__file__).resolve().parent


def model_path(name: str) -> Path:
    """Absolute path of a file in models/ (a relative `name`) or `name` itself if absolute."""
    path = Path(name)
    return path if path.is_absolute() else MODELS_DIR / path
