"""Running untrusted programs, for engine plugins: the sandboxed browser pool with its virtual
clock (`visphy_core.sandbox.browser`), sandboxed processes with hard limits
(`visphy_core.sandbox.process`) and the vendored JavaScript libraries pages may load
(`visphy_core.infra.js_assets`, collected from the registered engines by
`visphy_core.api.assets`)."""

from __future__ import annotations

from visphy_core.api.assets import assets_installed, require_assets, vendored_file
from visphy_core.infra.js_assets import AssetsMissing, JsAssets, VendorFiles
from visphy_core.sandbox.browser import BrowserPool, PageCapture, VIRTUAL_TIME_JS
from visphy_core.sandbox.process import (
    Limits,
    ProcessResult,
    describe_limit,
    limit_from_text,
    python_ro_paths,
    read_untrusted,
    run_sandboxed,
)

__all__ = [
    "assets_installed", "AssetsMissing", "BrowserPool", "describe_limit", "JsAssets",
    "limit_from_text", "Limits", "PageCapture", "ProcessResult", "python_ro_paths",
    "read_untrusted", "require_assets", "run_sandboxed", "vendored_file", "VendorFiles",
    "VIRTUAL_TIME_JS",
]
