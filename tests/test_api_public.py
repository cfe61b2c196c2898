"""The public contract re-exported by ``visphy_core.api``: every name resolves to the object its
module defines, lazily (importing the package imports no contract module)."""

import importlib
import subprocess
import sys

import pytest

import visphy_core.api as api


@pytest.mark.parametrize("name", api.__all__)
def test_every_public_name_is_the_object_its_module_defines(name):
    module = importlib.import_module(f"visphy_core.api.{api._PUBLIC[name]}")
    assert getattr(api, name) is getattr(module, name)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        api.Nope  # noqa: B018


def test_importing_the_package_imports_no_contract():
    code = ("import sys, visphy_core.api; "
            "print(sorted(m for m in sys.modules if m.startswith('visphy_core.api.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"
