"""The LiDAR tests' helper modules, importable by name (the tests run with ``--import-mode=importlib``, which puts
no test folder on the path): ``import tile_faults``."""

import importlib.util
import sys
from pathlib import Path

for _name in ("tile_faults",):
    _spec = importlib.util.spec_from_file_location(_name, Path(__file__).with_name(f"{_name}.py"))
    sys.modules[_name] = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(sys.modules[_name])
