"""Ground-truth simulators registered by ``world.engine``: Box2D (2D) and cannon-es (3D)."""
