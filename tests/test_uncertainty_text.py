"""A value with its standard error as text: the error to two significant digits, the value to the
same decimal (worked by hand below)."""

import math

import pytest
from ringlight.core.uncertainty_text import with_error


@pytest.mark.parametrize("value, error, text", [
    (0.191223145, 0.0031, "0.1912±0.0031"),
    (0.191223145, 0.00031, "0.19122±0.00031"),
    (12.3456, 1.2, "12.3±1.2"),
    (-0.00123, 0.00045, "-0.00123±0.00045"),
    (123456.7, 345.0, "123460±340"),  # the error's second digit is the tens
    (0.0, 0.02, "0.000±0.020"),
    (2.4812e-5, 1.3e-6, "(2.48±0.13)e-05"),  # plain decimals would need 7 places
    (1234567.0, 5000.0, "(1.2346±0.0050)e+06"),
    (1.0, 0.0999, "1.00±0.10"),  # the error rounds up a decade: still two digits
    (0.0996, 0.0996, "0.10±0.10"),
    (-1e-05, 1.0, "0.0±1.0"),  # not -0.0
    (3.0, 1e-9, "3±1e-09"),  # below float32's precision of the value: 7 digits at most
    (3.0, 5e-324, "3±4.9e-324"),
    (0.191223145, None, "0.1912"),  # no error yet: 4 significant digits
    (0.191223145, math.nan, "0.1912"),
    (3.0, 0.0, "3±0"),  # members all alike: the spread says 0
    (3.0, -1.0, "3"),
    (math.nan, 0.1, "undefined"),
])
def test_a_value_is_given_to_the_digit_its_error_allows(value, error, text):
    assert with_error(value, error) == text
