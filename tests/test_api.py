"""The public API as a script sees it: ``dir(cmrt)`` lists what ``__all__`` promises and nothing it uses to load
it, every name resolves to what the lazy table says, and the version is the installed distribution's."""

import importlib.metadata
import subprocess
import sys

import cmrt


def test_dir_lists_the_api_only():
    public = [n for n in dir(cmrt) if not n.startswith("_")]
    assert public == sorted(cmrt.__all__)
    assert not {"importlib", "TYPE_CHECKING", "os", "sys"} & set(public)


def test_every_api_name_resolves_from_the_module_it_is_documented_in():
    assert set(cmrt.__all__) == set(cmrt._API)
    for name, module in cmrt._API.items():
        assert getattr(cmrt, name) is getattr(importlib.import_module(module), name), name


def test_the_version_is_the_distributions():
    assert cmrt.__version__ == importlib.metadata.version("cmrt")
    out = subprocess.run([sys.executable, "-m", "cmrt.cli", "--version"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == f"cmrt {cmrt.__version__}", out
