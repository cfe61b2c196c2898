"""visphy's Hydra launchers, in the namespace Hydra scans for plugins (`visphy_plugins.launchers`
holds the code and says why)."""
