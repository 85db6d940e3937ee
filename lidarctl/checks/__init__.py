"""Accuracy checks: classes against truth, heights and plan against surveyed points, map vectors."""
