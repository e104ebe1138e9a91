"""The pool launcher (pipeline.app.launcher) where Hydra looks for launchers."""
