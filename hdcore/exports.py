"""A package's public names, declared once in its stub ``__init__.pyi`` and imported on first use.

Each of ``lidarsim``, ``hdlabels`` and ``hdnet`` lists its public API (docs/api.md) as re-exports
in ``__init__.pyi``, one ``from PACKAGE.MODULE import NAME as NAME`` per name: type checkers and
editors read the stub, and :func:`lazy_exports` reads the same lines at run time and gives the
package a module ``__getattr__`` (PEP 562) that imports a name's module when the name is first
used. ``import hdnet`` therefore imports no PyTorch, ``import lidarsim`` no Open3D, and ``hd
--help`` stays as fast as before; ``hdnet.fit`` imports what ``fit`` needs when it is looked up.

A public function named like its own module (``fit`` in ``hdnet/fit.py``) is the package's
attribute, whichever of the two was imported first: the import system's binding of the submodule
to the package is declined for those names. The module itself is ``sys.modules["hdnet.fit"]``
(``importlib.import_module("hdnet.fit")``, e.g. to monkeypatch it), and ``from hdnet.fit import
FitConfig`` works as ever.
"""

from __future__ import annotations

import ast
import importlib
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

# The package beneath every other: a package may re-export its names (the root error, HdError).
CORE = "hdcore"

STUB_SUFFIX = ".pyi"


class ExportError(ImportError):
    """A stub that is not a plain list of re-exports (a defect of hd itself, found as it is imported)."""


def stub_exports(stub: str | Path, package: str) -> dict[str, tuple[str, str]]:
    """Public name -> (module, name in that module) of every ``from M import N as N`` line of ``stub``.

    The stub holds its docstring and such lines only, each importing from a module of ``package``
    and re-exporting under the imported name (``as N``, the typing convention for a re-export).

    Raises:
        ExportError: any other statement, a relative import, a module outside ``package`` (and
            the core beneath every package, ``hdcore``), a renamed or repeated name.
    """
    path = Path(stub)
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    exports: dict[str, tuple[str, str]] = {}
    for k, node in enumerate(tree.body):
        if k == 0 and isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            continue  # the docstring
        if not isinstance(node, ast.ImportFrom) or node.level or not node.module:
            where = f"{path}:{getattr(node, 'lineno', 0)}"
            raise ExportError(f"{where}: only `from {package}.MODULE import NAME as NAME` lines belong here")
        if not node.module.startswith((f"{package}.", f"{CORE}.")):
            raise ExportError(f"{path}:{node.lineno}: {node.module} is not a module of {package} or of {CORE}")
        for alias in node.names:
            if alias.asname != alias.name or alias.name in exports:
                name = alias.name
                raise ExportError(f"{path}:{node.lineno}: re-export {name} once, as `{name} as {name}`")
            exports[alias.name] = (node.module, alias.name)
    return exports


class _Package(ModuleType):
    """A package whose public names win over its submodules of the same name (module docstring)."""

    def __setattr__(self, name: str, value: Any) -> None:
        exports = self.__dict__.get("__all__", ())
        if isinstance(value, ModuleType) and name in exports and value.__name__ == f"{self.__name__}.{name}":
            return  # the import system binding hdnet.fit (the module) over hdnet.fit (the function)
        super().__setattr__(name, value)


def lazy_exports(package: str, init_file: str) -> tuple[list[str], Callable[[str], Any], Callable[[], list[str]]]:
    """``__all__``, ``__getattr__`` and ``__dir__`` of the package ``package`` whose ``__init__.py`` is
    ``init_file``, from the stub beside it; its names are imported on first use.

    Called once by each package's ``__init__.py``:
    ``__all__, __getattr__, __dir__ = lazy_exports(__name__, __file__)``.
    """
    exports = stub_exports(Path(init_file).with_suffix(STUB_SUFFIX), package)
    module = sys.modules[package]
    namespace = module.__dict__

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        source, attribute = exports[name]
        value = getattr(importlib.import_module(source), attribute)
        namespace[name] = value  # looked up once
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(exports))

    module.__class__ = _Package
    return sorted(exports), __getattr__, __dir__
