"""Environments that ship with sb3-cmzdril (registered with gymnasium on import)."""
