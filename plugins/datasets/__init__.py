"""Dataset plugins: ``generated`` (VisPhyBench regenerated), ``original`` (the published layout),
``tiny`` (a fixture for plugin authors)."""
