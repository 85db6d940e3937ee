"""The production chain: every stage over one project folder, resumable, with a summary at the end.

- ``results``: the record each stage returns (``StageResult`` and one subclass per stage);
- ``runner``: ``Stage``, stamps (``work/stages/<stage>.json``), ``run_stages``, ``format_summary``;
- ``options``: the stage sections of ``project.toml`` (``read_options``, ``ChainSettings``);
- ``stages``: the chain built from a project and its options (``Chain``, ``chain_stages``);
- ``run``: ``aerotri run`` and ``aerotri demo`` as library calls (``run_project``, ``run_demo``);
- ``cli``: the ``aerotri run`` and ``aerotri demo`` commands.
"""

_WHERE = {
    "ChainSettings": "options", "read_options": "options",
    "Stage": "runner", "format_summary": "runner", "is_current": "runner", "run_stages": "runner",
    "stamp_path": "runner", "StageResult": "results",
    "Chain": "stages", "chain_stages": "stages",
    "run_project": "run", "run_demo": "run",
}
__all__ = sorted(_WHERE)


def __getattr__(name):
    # Lazy: the command line imports aerotri.chain.cli without the stages (every `aerotri` command would
    # otherwise load the whole toolkit first).
    if name in _WHERE:
        import importlib

        return getattr(importlib.import_module(f"aerotri.chain.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'aerotri.chain' has no attribute {name!r}")
