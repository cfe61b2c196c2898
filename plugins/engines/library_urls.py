"""Library URLs a program loads, served from vendored copies: CDN and local URLs mapped to the
vendored file (`vendored_url`), the version a URL asks for against the version served, and the
import maps a page declares merged into the vendored one. Each rewrite is recorded as a
`Substitution`, so the render's notes say which library the program got instead of the one it
named."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from functools import cache
from urllib.parse import urlparse


from visphy_plugins.engines.assets import BROWSER_ASSETS

THREE_ESM = "/vendor/npm/three-esm/build/three.module.js"
IMPORT_MAP = {
    "imports": {
        "three": THREE_ESM,
        "three/webgpu": "/vendor/npm/three-esm/build/three.webgpu.js",
        "three/tsl": "/vendor/npm/three-esm/build/three.tsl.js",
        "three/addons/": "/vendor/npm/three-esm/examples/jsm/",
        "three/examples/jsm/": "/vendor/npm/three-esm/examples/jsm/",
        "cannon-es": "/vendor/cannon-es.js",
    }
}

CDN_HOSTS = ("cdn.jsdelivr.net", "fastly.jsdelivr.net", "unpkg.com", "cdnjs.cloudflare.com",
             "esm.sh", "cdn.esm.sh", "esm.run", "cdn.skypack.dev", "ga.jspm.io", "jspm.dev",
             "cdn.jsdelivr.com", "threejs.org", "cdn.rawgit.com", "rawcdn.githack.com")
_PACKAGE_ALIASES = {"three": "three", "three.js": "three", "cannon": "cannon",
                    "cannon.js": "cannon", "cannon-es": "cannon-es", "p5": "p5", "p5.js": "p5",
                    "matter-js": "matter-js", "matter.js": "matter-js", "matter": "matter-js"}
_URL_LITERAL = re.compile(
    r"""(["'`])((?:https?:)?//(?:%s)/[^"'`\s]*)\1""" % "|".join(re.escape(h) for h in CDN_HOSTS),
    re.I)
_SCRIPT_SRC_TAG = re.compile(
    r"<script\b([^>]*?)\bsrc\s*=\s*([\"'])([^\"']*)\2([^>]*)>\s*</script>", re.I)
_IMPORT_MAP_TAG = re.compile(
    r"<script\b[^>]*\btype\s*=\s*[\"']?importmap[\"']?[^>]*>(.*?)</script>", re.I | re.S)


def _cdn_package(url: str) -> tuple[str, str] | None:
    """(package, path inside the package) of a CDN URL, or None for another host."""
    parsed = urlparse(url if "//" in url[:8] or url.startswith("http") else "https:" + url)
    host = (parsed.hostname or "").lower()
    if host not in CDN_HOSTS:
        return None
    parts = [p for p in parsed.path.split("/") if p]
    if host == "threejs.org":  # https://threejs.org/build/three.module.js
        return "three", "/".join(parts)
    if parts and parts[0] in ("npm", "gh"):
        parts = parts[1:]
    if parts and parts[0].startswith("npm:"):
        parts[0] = parts[0][4:]
    if len(parts) >= 2 and parts[0] == "ajax" and parts[1] == "libs":  # cdnjs: name/version/file
        parts = parts[2:]
        if len(parts) < 2:
            return None
        name, rest = parts[0], parts[2:]
    else:
        if parts and re.fullmatch(r"v\d+", parts[0]):  # esm.sh build prefix
            parts = parts[1:]
        if not parts:
            return None
        if parts[0].startswith("@") and len(parts) > 1:
            name, rest = parts[0] + "/" + parts[1], parts[2:]
        else:
            name, rest = parts[0], parts[1:]
        name = name.rsplit("@", 1)[0] if "@" in name[1:] else name
    pkg = _PACKAGE_ALIASES.get(name.lower())
    return (pkg, "/".join(rest)) if pkg else None


def _local_package(url: str) -> tuple[str, str] | None:
    """A library guessed from a non-CDN script path by its file name (``js/three.min.js``)."""
    name = url.rsplit("/", 1)[-1].split("?", 1)[0].lower()
    for pkg, pattern in (("cannon-es", r"cannon-es(\.min)?\.m?js"),
                         ("cannon", r"cannon(\.min)?\.js"),
                         ("three", r"three(\.module|\.min|\.module\.min)?\.m?js"),
                         ("p5", r"p5(\.sound)?(\.min)?\.js"),
                         ("matter-js", r"matter(-js)?(\.min)?\.js")):
        if re.fullmatch(pattern, name):
            return pkg, name
    return None


def vendored_url(url: str, allow_local: bool = False) -> str | None:
    """The fake-origin path serving a library URL (CDN or, with ``allow_local``, a bare file name
    such as ``three.min.js``), or None when it is not one of the pinned libraries."""
    hit = _cdn_package(url) or (_local_package(url) if allow_local else None)
    if hit is None:
        return None
    pkg, sub = hit
    base = sub.lower().rstrip("/").rsplit("/", 1)[-1]  # file name ("" for the bare package)
    if not base.endswith((".mjs", ".js", ".cjs")) and base not in ("build", "dist", "lib", "+esm"):
        base = ""  # a package-level URL: https://esm.sh/three@0.160.0, .../es2022/…
    if pkg == "three":
        for marker in ("examples/jsm/", "addons/"):
            if marker in sub:
                return "/vendor/npm/three-esm/examples/jsm/" + sub.split(marker, 1)[1]
        if sub.rstrip("/").endswith(("examples/jsm", "addons")):
            return "/vendor/npm/three-esm/examples/jsm/"
        if base in ("three.min.js", "three.js", "three.cjs"):
            return "/vendor/three.min.js"
        if base.startswith("three.webgpu"):
            return "/vendor/npm/three-esm/build/three.webgpu.js"
        if base.startswith("three.tsl"):
            return "/vendor/npm/three-esm/build/three.tsl.js"
        if base == "three.core.js":
            return "/vendor/npm/three-esm/build/three.core.js"
        if base in ("", "build", "+esm", "three.module.js", "three.module.min.js", "three.mjs",
                    "index.js"):
            return THREE_ESM  # the ES module, also the bare package on esm.sh / skypack
        return None  # e.g. examples/js/… (classic add-ons, not vendored)
    if pkg == "cannon-es":
        ok = base in ("", "dist", "+esm") or base.startswith("cannon-es")
        return "/vendor/cannon-es.js" if ok else None
    if pkg == "cannon":
        ok = base in ("", "build") or base.startswith("cannon")
        return "/vendor/cannon.min.js" if ok else None
    if pkg == "p5":
        if "sound" in base:
            return "/vendor/npm/p5/lib/addons/p5.sound.min.js"
        ok = base in ("", "lib") or base in ("p5.js", "p5.min.js")
        return "/vendor/p5.min.js" if ok else None
    if pkg == "matter-js":
        ok = base in ("", "build") or base.startswith("matter")
        return "/vendor/matter.min.js" if ok else None
    return None


# ------------------------------------------------------------------ versions and substitutions

#: Served path prefix -> (package, lock entry) of the vendored copy behind it.
_SERVED = (("/vendor/npm/three-esm/", "three", "three-esm"),
           ("/vendor/three.module.js", "three", "three-esm"),
           ("/vendor/three.core.js", "three", "three-esm"),
           ("/vendor/npm/three/", "three", "three"),
           ("/vendor/three.min.js", "three", "three"),
           ("/vendor/npm/cannon-es/", "cannon-es", "cannon-es"),
           ("/vendor/cannon-es.js", "cannon-es", "cannon-es"),
           ("/vendor/npm/cannon/", "cannon", "cannon"),
           ("/vendor/cannon.min.js", "cannon", "cannon"),
           ("/vendor/npm/p5/", "p5", "p5"),
           ("/vendor/p5.min.js", "p5", "p5"),
           ("/vendor/npm/matter-js/", "matter-js", "matter-js"),
           ("/vendor/matter.min.js", "matter-js", "matter-js"))


@cache
def _locked_versions() -> dict[str, str]:
    """Lock entry name (``three``, ``three-esm``...) -> the exact version vendored."""
    return BROWSER_ASSETS.locked_versions()


def served_version(path: str) -> tuple[str, str] | None:
    """(package, version) of the vendored file a page is served at ``path``, or None."""
    for prefix, package, entry in _SERVED:
        if path == prefix or (prefix.endswith("/") and path.startswith(prefix)):
            return package, _locked_versions().get(entry, "?")
    return None


_VERSION = r"v?\d+(?:\.\d+){0,2}(?:[-+][\w.]+)?"


def requested_version(url: str) -> str | None:
    """The library version a URL asks for (``three@0.160.0``, ``^1.9``, cdnjs ``/r128/``), or
    None when it names none (a bare package, ``latest``, a local file)."""
    parsed = urlparse(url if "//" in url[:8] or url.startswith("http") else "https:" + url)
    parts = [p for p in parsed.path.split("/") if p]
    if (parsed.hostname or "").lower() == "cdnjs.cloudflare.com" and parts[:2] == ["ajax", "libs"]:
        version = parts[3] if len(parts) > 3 else ""
    else:
        version = ""
        for part in parts:
            if "@" in part[1:]:
                version = part.rsplit("@", 1)[1]
                break
    version = version.lstrip("^~=")
    if re.fullmatch(r"r\d+", version):  # three.js release names: r128 = 0.128
        version = f"0.{version[1:]}"
    return version.lstrip("v") if re.fullmatch(_VERSION, version) else None


def same_version(requested: str, served: str) -> bool:
    """Whether a vendored ``served`` version satisfies ``requested``: equal major.minor (patch
    releases keep the API); a requested major alone matches any minor of it."""
    want = re.split(r"[-+]", requested, 1)[0].split(".")[:2]
    have = re.split(r"[-+]", served, 1)[0].split(".")[:2]
    return have[:len(want)] == want


@dataclass(frozen=True)
class Substitution:
    """A library URL of the program and what the page is served instead."""

    requested: str              # the URL (or import-map entry) as the program wrote it
    version: str | None         # the version it asks for, None when it names none
    served: str                 # the vendored path served instead
    package: str
    served_version: str
    how: str = "rewritten"      # rewritten | preloaded (the template already loaded it)

    @property
    def substituted(self) -> bool:
        """A different version than the one asked for (an unversioned URL is not)."""
        return self.version is not None and not same_version(self.version, self.served_version)

    def describe(self) -> str:
        asked = f"{self.package} {self.version}" if self.version else "no version"
        served = f"{self.served} ({self.package} {self.served_version})"
        if self.how == "preloaded":
            served = f"the page's preloaded {served}"
        kind = "library substituted" if self.substituted else "library served from vendor"
        return f"[visphy] {kind}: {self.requested} ({asked}) -> {served}"


def _substitution(url: str, target: str, how: str = "rewritten") -> Substitution | None:
    hit = served_version(target)
    if hit is None:
        return None
    return Substitution(url, requested_version(url), target, hit[0], hit[1], how)


def _merge_import_maps(body: str, notes: list | None = None) -> tuple[str, dict]:
    """Remove the program's import maps and merge them under ours (ours win on conflicts)."""
    merged = {"imports": dict(IMPORT_MAP["imports"])}
    theirs: dict = {"imports": {}, "scopes": {}}

    def take(m: re.Match) -> str:
        try:
            data = json.loads(m.group(1))
        except json.JSONDecodeError:
            return m.group(0)  # malformed: left for the browser to report
        if isinstance(data, dict):
            theirs["imports"].update(data.get("imports") or {})
            theirs["scopes"].update(data.get("scopes") or {})
        return ""

    body = _IMPORT_MAP_TAG.sub(take, body)
    for key, value in theirs["imports"].items():
        if isinstance(value, str):
            merged["imports"].setdefault(key, vendored_url(value) or value)
            if notes is not None and merged["imports"][key] != value:
                notes.append(_substitution(value, merged["imports"][key]))
    if theirs["scopes"]:
        merged["scopes"] = theirs["scopes"]
    return body, merged
