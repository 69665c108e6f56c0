"""phrt_addon/finite.py: np.nan_to_num's result, without its copy when every value is finite."""
import numpy as np
import pytest

from phrt.phrt_addon.finite import finite


@pytest.mark.parametrize("kwargs", [{}, {"nan": 1.0, "posinf": 5.0, "neginf": -5.0}, {"nan": np.inf}])
def test_finite_equals_nan_to_num(kwargs):
    values = np.array([[0.5, np.nan, np.inf], [-np.inf, 2.0, -1.0]])
    np.testing.assert_array_equal(finite(values, **kwargs), np.nan_to_num(values, **kwargs))
    assert np.isnan(values[0, 1]) and np.isinf(values[0, 2])  # the input is left as it was


def test_finite_input_is_returned_itself_as_float64():
    values = np.array([1.0, 2.0])
    assert finite(values) is values
    ints = finite([1, 2])
    assert ints.dtype == np.float64 and ints.tolist() == [1.0, 2.0]
