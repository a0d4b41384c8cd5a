"""Dynamic Gaussian methods: which class a run's ``model.method`` names.

A method is a subclass of ``DynamicGaussians`` (``ftgspp/methods/base.py``, the interface).
``model.method`` is either a built-in name or ``"module:Class"``, a class anywhere on the
Python path, so a method from outside this package needs no registration step and works in
every process a run may train in (``ftgspp.runtime.child``, a study's launcher):

    ftgspp train model=stg                              # built-in: conf/model/stg.yaml
    ftgspp train model.method=my_pkg.gaussians:Static   # yours (docs/methods.md)

``register_method`` adds a short name for a class in this process (tests, notebooks).
"""

from __future__ import annotations

import importlib

from ftgspp.errors import InputError
from ftgspp.methods.base import DynamicGaussians, GaussiansAt

__all__ = ["DynamicGaussians", "GaussiansAt", "method_class", "method_names", "register_method"]

# built-in methods, imported on first use
BUILTIN = {
    "freetime": "ftgspp.methods.freetime:FreeTimeGaussians",  # FreeTimeGS and FreeTimeGS++ (model=ftgs, model=ftgspp)
    "stg": "ftgspp.methods.stg:SpacetimeGaussians",  # Spacetime Gaussians, lite (model=stg)
}
_REGISTERED: dict[str, type] = {}


def register_method(name: str, cls: type) -> type:
    """Make ``model.method=<name>`` select ``cls`` in this process; returns ``cls``."""
    if not (isinstance(cls, type) and issubclass(cls, DynamicGaussians)):
        raise TypeError(f"{cls!r} is not a DynamicGaussians subclass")
    _REGISTERED[name] = cls
    return cls


def method_names() -> list[str]:
    """Every short name ``model.method`` accepts in this process."""
    return sorted({*BUILTIN, *_REGISTERED})


def method_class(name: str) -> type:
    """The class ``model.method=<name>`` selects; one-line ``InputError`` when there is none."""
    if name in _REGISTERED:
        return _REGISTERED[name]
    target = BUILTIN.get(name, name)
    if ":" not in target:
        raise InputError("model.method", f"unknown method '{name}' (choose from {', '.join(method_names())},"
                         " or give module:Class)")
    module, _, attr = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as err:
        raise InputError("model.method", f"cannot import '{target}': {err}") from err
    if not (isinstance(cls, type) and issubclass(cls, DynamicGaussians)):
        raise InputError("model.method", f"'{target}' is not a DynamicGaussians subclass (ftgspp/methods/base.py)")
    return cls

