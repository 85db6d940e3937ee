"""Layer 4, quality assurance: the consolidated accuracy report of a project (``report``) with its
command (``cli``). Reads the stages' results through the project folder; the tolerance tables are
``aerotri.core.tolerances``."""
