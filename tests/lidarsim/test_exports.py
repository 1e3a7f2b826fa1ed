"""The packages' public names (``hdcore.exports``): declared once in ``__init__.pyi``, imported on first
use, and a function named like its module is the package's attribute whatever was imported first."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path
from types import ModuleType

import pytest

from hdcore.exports import ExportError, stub_exports

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("numpy", "torch", "open3d", "rasterio", "h5py", "scipy", "numba", "dask", "matplotlib", "click")


def python(code: str) -> str:
    """Run ``code`` in a fresh interpreter at the repository root; its stdout (it must succeed)."""
    result = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_importing_the_packages_imports_none_of_their_libraries():
    out = python(
        f"""
        import sys
        import lidarsim, hdlabels, hdnet
        print(sorted(m for m in {HEAVY!r} if m in sys.modules))
        print(len(lidarsim.__all__), len(hdlabels.__all__), len(hdnet.__all__))
        import hdlabels.store  # a module of the package, as ever
        print("torch" in sys.modules, callable(hdnet.fit), "torch" in sys.modules)
        """
    )
    lines = out.splitlines()
    assert lines[0] == "[]" and all(int(n) > 10 for n in lines[1].split())
    assert lines[2] == "False True True"  # hdnet.fit imported PyTorch when it was looked up, not before


@pytest.mark.parametrize(
    "first",
    [
        "import hdnet.fit, hdnet.evaluate, hdnet.detect",  # the modules first
        "from hdnet.detect import DetectRun; from hdnet.fit import FitConfig; from hdnet.evaluate import evaluate",
        "import hdcli.detect_job, hdcli.train_job, hdcli.eval_job, hdcli.pipeline",  # what the CLI imports
        "import hdnet; hdnet.detect_dem; hdnet.FitConfig; hdnet.EvalConfig",  # names that import those modules
        "import hdnet",
    ],
)
def test_a_function_named_like_its_module_is_the_packages_attribute_whatever_came_first(first):
    out = python(
        f"""
        {first}
        import importlib, types
        import hdnet
        from hdnet import detect, evaluate, fit
        for name, value in (("fit", fit), ("evaluate", evaluate), ("detect", detect)):
            module = importlib.import_module("hdnet." + name)
            assert isinstance(module, types.ModuleType) and module.__name__ == "hdnet." + name
            assert value is getattr(hdnet, name) is getattr(module, name), name
            assert callable(value) and value.__module__ == "hdnet." + name, name
        print("ok")
        """
    )
    assert out == "ok\n"


def test_the_packages_list_their_names_and_refuse_others():
    import hdnet
    import lidarsim
    from lidarsim import limits  # a module that is no public name: imported as a submodule

    assert limits.__name__ == "lidarsim.limits"
    names: list[str] = getattr(hdnet, "__all__")  # noqa: B009 - the stub, which type checkers read, has no __all__
    assert set(names) <= set(dir(hdnet)) and "detect_dem" in dir(hdnet)
    with pytest.raises(AttributeError, match="module 'lidarsim' has no attribute 'build_datset'"):
        _ = lidarsim.build_datset  # type: ignore[attr-defined]  # the misspelling is the point
    assert lidarsim.build_dataset.__module__ == "lidarsim.build"


@pytest.mark.parametrize(
    ("line", "needle"),
    [
        ("import lidarsim.build", "only `from lidarsim.MODULE import NAME as NAME` lines belong here"),
        ("def f() -> None: ...", "only `from lidarsim.MODULE import NAME as NAME` lines belong here"),
        ("from .build import BuildConfig as BuildConfig", "only `from lidarsim.MODULE import NAME as NAME`"),
        ("from hdnet.fit import fit as fit", "hdnet.fit is not a module of lidarsim"),
        ("from lidarsim.build import BuildConfig", "re-export BuildConfig once, as `BuildConfig as BuildConfig`"),
        ("from lidarsim.build import BuildConfig as Config", "re-export BuildConfig once"),
        ("from lidarsim.terrain import DTM as DTM\nfrom lidarsim.terrain import DTM as DTM", "re-export DTM once"),
    ],
)
def test_a_stub_that_is_not_a_plain_list_of_re_exports_is_refused(tmp_path, line, needle):
    stub = tmp_path / "__init__.pyi"
    stub.write_text(f'"""Docstring."""\n\nfrom lidarsim.errors import HdError as HdError\n{line}\n')
    with pytest.raises(ExportError, match=needle):
        stub_exports(stub, "lidarsim")


def test_the_stubs_are_what_the_packages_export():
    import hdlabels
    import hdnet
    import lidarsim

    modules: tuple[ModuleType, ...] = (lidarsim, hdlabels, hdnet)
    for module in modules:
        assert module.__file__ is not None
        exports = stub_exports(Path(module.__file__).with_suffix(".pyi"), module.__name__)
        assert sorted(exports) == module.__all__
        assert all(source.startswith((f"{module.__name__}.", "hdcore.")) for source, _ in exports.values())


@pytest.mark.parametrize(("package", "names"), [("hdnet", ("fit", "evaluate", "detect")), ("lidarsim", ("make_dtm",))])
def test_the_package_says_how_to_reach_a_module_its_function_shadows(package, names):
    """Each function named like its module is named in its package's docstring, with the one way
    to reach the module, and that way gives the module."""
    import importlib

    module = importlib.import_module(package)
    shadowed = [n for n, (source, _) in stub_exports(ROOT / package / "__init__.pyi", package).items()
                if source == f"{package}.{n}"]  # fmt: skip
    assert sorted(shadowed) == sorted(names)
    doc = module.__doc__ or ""
    first = names[1] if len(names) > 1 else names[0]
    assert f'importlib.import_module("{package}.{first}")' in doc
    for name in names:
        assert f"{package}.{name}" in doc
        assert callable(getattr(module, name)) and not isinstance(getattr(module, name), ModuleType)
        assert isinstance(importlib.import_module(f"{package}.{name}"), ModuleType)
