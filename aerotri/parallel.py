"""Re-export of the task executor (aerotri may import lidarctl, not the other way)."""

from lidarctl.parallel import Executor, activate, executor_for, local_executor, scheduler_options

__all__ = ["Executor", "activate", "executor_for", "local_executor", "scheduler_options"]
