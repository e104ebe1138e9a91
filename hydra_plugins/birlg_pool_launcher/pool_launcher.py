"""Hydra finds launchers only in the hydra_plugins namespace package: the pool launcher of
pipeline.app.launcher under its name here (conf/hydra/launcher/pool.yaml)."""

from pipeline.app.launcher import PoolLauncher as _PoolLauncher


class PoolLauncher(_PoolLauncher):
    pass
