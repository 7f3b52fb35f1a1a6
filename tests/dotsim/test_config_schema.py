"""dotsim.config_schema's own examples (the generator's and trainer's configs test the rest:
tests/generator/test_config.py)."""

import doctest

from dotsim import config_schema


def test_docstring_examples():
    result = doctest.testmod(config_schema)
    assert result.attempted > 0 and result.failed == 0
