"""sb3-cmzdril: CMZ-DRIL and its baselines for stable-baselines3."""
from sb3_cmzdril import envs  # noqa: F401  (registers WaypointNav-v0 with gymnasium)
from sb3_cmzdril.demos import Demonstrations

__version__ = "0.1.0"
__all__ = ["Demonstrations"]
