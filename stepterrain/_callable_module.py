"""A module callable as its entry point, shared by :mod:`stepterrain.batch` and :mod:`stepterrain.stepped`.

The package's attributes ``stepterrain.batch`` and ``stepterrain.stepped`` are the modules, and calling one runs the
module's function of the same name: ``st.stepped(dem, interval=100.0)`` and ``st.stepped.thresholds_of`` both work,
as do ``st.batch(...)`` and ``st.batch.LOCAL_CLUSTER_MALLOC``. When the package bound the function, the module's other
names were reachable only by ``from stepterrain.stepped import ...``.
"""

from __future__ import annotations

import importlib
import inspect
import sys
import types
from typing import Any

__all__ = ["make_module_callable"]


def make_module_callable(module_name: str) -> None:
    """Make the imported module ``module_name`` callable as its function named like its last component.

    Calling the module calls the function looked up at call time (so a monkeypatched function is the one called);
    ``inspect.signature`` and ``help()`` show the function's parameters, and pickle / cloudpickle take the module by
    name (the function pickled by name too). Each module gets its own ``ModuleType`` subclass.
    """
    entry = module_name.rpartition(".")[2]

    class CallableModule(types.ModuleType):
        __doc__ = f"The module {module_name}, callable as its entry point :func:`{module_name}.{entry}`."

        def __call__(self, *args: Any, **kwargs: Any) -> Any:
            return getattr(self, entry)(*args, **kwargs)

        @property
        def __signature__(self) -> inspect.Signature:  # inspect.signature(module) and help() show the entry point's
            return inspect.signature(getattr(self, entry))

        def __reduce__(self) -> tuple[Any, tuple[str]]:  # by name, as the function was (cloudpickle refused a module)
            return importlib.import_module, (self.__name__,)

    CallableModule.__module__, CallableModule.__qualname__ = module_name, "CallableModule"
    sys.modules[module_name].__class__ = CallableModule
