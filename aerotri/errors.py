"""Re-export of the shared input error (aerotri may import lidarctl, not the other way)."""

from lidarctl.errors import InputError, exit_on_input_error

__all__ = ["InputError", "exit_on_input_error"]
