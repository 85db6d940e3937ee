"""The ``aerotri crs`` command (interfaces layer: ``cli.py``); its library is ``aerotri.geom.crs``."""
