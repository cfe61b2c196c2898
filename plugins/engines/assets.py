"""The npm packages the browser engines' pages load (`Engine.js_assets`).

``js_vendor/package-lock.json`` pins every library with its integrity hash; ``visphy setup``
installs it into the asset cache (`visphy_core.api.sandbox.JsAssets`). The short names are what
the engines' templates and `visphy_plugins.engines.browser_base.vendored_url` serve as
``/vendor/<name>``.
"""

from __future__ import annotations

from pathlib import Path

from visphy_core.api.sandbox import JsAssets

BROWSER_ASSETS = JsAssets(
    source=Path(__file__).with_name("js_vendor"),
    libraries={
        "three.min.js": "three/build/three.min.js",            # r160 UMD: global THREE
        "three.module.js": "three-esm/build/three.module.js",  # r187 ES module
        "cannon.min.js": "cannon/build/cannon.min.js",        # cannon.js 0.6.2 UMD: global CANNON
        "cannon-es.js": "cannon-es/dist/cannon-es.js",          # cannon-es ES module
        "p5.min.js": "p5/lib/p5.min.js",
        "matter.min.js": "matter-js/build/matter.min.js",
    },
)
