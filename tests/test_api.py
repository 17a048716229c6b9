"""The public namespace: every exported name resolves, lazily loaded names are the modules' own objects."""

from __future__ import annotations

import importlib

import pytest

import stepterrain as st


@pytest.mark.parametrize("name", st.__all__)
def test_every_exported_name_resolves(name):
    assert getattr(st, name) is not None


@pytest.mark.parametrize("name, module", sorted(st._LAZY.items()))
def test_lazy_names_are_the_capability_modules_objects(name, module):
    assert getattr(st, name) is getattr(importlib.import_module(f"stepterrain.{module}"), name)


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        st.not_a_name  # noqa: B018


def test_function_names_survive_importing_their_modules():
    import stepterrain.stepped  # noqa: F401 - the submodule import must not shadow the function

    assert callable(st.stepped) and st.stepped.__module__ == "stepterrain.stepped"


@pytest.mark.parametrize("name", sorted(st._SUBMODULES))
def test_submodules_are_attributes(name):
    assert getattr(st, name).__name__ == f"stepterrain.{name}"
