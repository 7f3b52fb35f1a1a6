"""The public facade in dotsim/__init__.py: its docstring examples run (generate's, in
generator/driver.py, renders a tiny scene), its names are the real functions, and `import dotsim`
loads neither bpy nor torch."""

import doctest
import subprocess
import sys
from pathlib import Path

import pytest

import dotsim
import dotsim.dataset
import dotsim.rig.geometry
import generator.config
import generator.driver

EXAMPLES = {test.name: test for module in (dotsim, generator.driver.generate)
            for test in doctest.DocTestFinder().find(module) if test.examples}


def test_the_examples_are_where_the_readme_says():
    assert sorted(EXAMPLES) == ["dotsim", "generate"]


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_docstring_examples(name):
    result = doctest.DocTestRunner().run(EXAMPLES[name])
    assert result.attempted > 0 and result.failed == 0, f"{name}: {result.failed} example(s) failed (above)"


def test_the_names_are_the_real_functions():
    assert dotsim.open_dataset is dotsim.dataset.open_dataset
    assert dotsim.read_frame is dotsim.dataset.read_frame
    assert dotsim.Rig is dotsim.rig.geometry.Rig
    assert dotsim.load_config is generator.config.load_config
    assert dotsim.generate is generator.driver.generate
    assert set(dotsim.__all__) <= set(dir(dotsim))
    with pytest.raises(AttributeError, match="no attribute 'generat'"):
        dotsim.generat  # noqa: B018


def test_import_dotsim_loads_neither_bpy_nor_torch():
    """Checked in a fresh interpreter: after `import dotsim` and after touching every public name."""
    code = ("import sys, dotsim; before = {'bpy', 'torch'} & set(sys.modules); "
            "[getattr(dotsim, name) for name in dotsim.__all__]; "
            "print(sorted(before), sorted({'bpy', 'torch'} & set(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(dotsim.__file__).parents[1]).stdout
    assert out.split("\n")[0] == "[] []", out
