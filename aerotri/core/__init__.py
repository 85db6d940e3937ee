"""Layer 1, core: the error hierarchy, atomic writes and temporaries, resumable stages, the task executor,
logging and progress, the project folder, and the click plumbing every command line shares. Imports nothing
of ours beyond this package."""
