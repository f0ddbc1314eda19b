"""Lazy re-exports for the subpackages: a name's module is imported on first use.

The camera side (``sb-encode --raw``) must not import numpy or numba; a subpackage
``__init__`` that imported all its modules eagerly would drag them in.
"""

import importlib


def attach(package, modules):
    """Return ``__getattr__``, ``__dir__`` and ``__all__`` for ``package``.

    Parameters
    ----------
    package : str
        The subpackage's ``__name__``.
    modules : dict of str to list of str
        Private module name (relative to ``package``) to the public names it provides.
    """
    owner = {name: module for module, names in modules.items() for name in names}
    names = sorted(owner)

    def __getattr__(name):
        if name in owner:
            value = getattr(importlib.import_module(f"{package}.{owner[name]}"), name)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__():
        return names

    return __getattr__, __dir__, list(names)
