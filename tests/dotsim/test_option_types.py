"""dotsim.option_types: the argparse types every command's numeric options use."""

import argparse
import doctest

import pytest

from dotsim import option_types


def test_docstring_examples():
    result = doctest.testmod(option_types)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize("text", ["-1", "x", "1.5", "", "1e3"])
def test_integer_refuses_naming_value_and_range(text):
    with pytest.raises(argparse.ArgumentTypeError, match=rf"^{text!r}: allowed: an integer >= 0$"):
        option_types.integer(0)(text)
