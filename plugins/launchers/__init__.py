"""Hydra launchers that visphy ships itself.

A Ray launcher (``hydra/launcher=ray_local`` for a local Ray cluster, ``hydra/launcher=ray`` for
an existing one) written against Ray's public API (``ray.init``, ``ray.remote``, ``ray.get``).
Why not hydra-ray-launcher 1.2.2: it pins ``cloudpickle<3`` while joblib 1.6 (behind our
hydra-joblib-launcher) needs ``cloudpickle>=3``, so installing it downgrades joblib to 1.5 and
cloudpickle to 2.2 and adds ``ray[default]`` with boto3, grpcio and about 20 other packages; Ray
itself installs alone (``ray`` + ``msgpack``) and this launcher needs nothing more.

Hydra accepts a launcher only from its ``hydra_plugins`` namespace, so the Launcher class lives
in ``hydra_plugins/visphy_launchers/`` (installed as the package
``hydra_plugins.visphy_launchers``) and only delegates here: `ray_config` registers its
structured config, `ray_jobs` starts Ray and runs the jobs.
"""
