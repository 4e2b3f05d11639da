import numpy as np
import pytest
import torch

from cuboidlib._checks import (
    as_float_tensor,
    check_finite,
    check_positive,
    check_same_leading,
    check_shape,
    check_unit_vectors,
)


def test_as_float_tensor_converts_arrays_and_integers():
    t = as_float_tensor(np.array([[1, 2, 3]]), "x")
    assert t.dtype == torch.get_default_dtype() and t.tolist() == [[1.0, 2.0, 3.0]]
    kept = torch.zeros(2, dtype=torch.float64, requires_grad=True)
    assert as_float_tensor(kept, "x") is kept
    with pytest.raises(TypeError, match="x must be a tensor"):
        as_float_tensor(object(), "x")


def test_check_shape_binds_symbols_and_names_the_problem():
    assert check_shape(torch.zeros(2, 5, 3), ("B", "N", 3), "points") == {"B": 2, "N": 5}
    with pytest.raises(ValueError, match=r"points must have shape \(B, N, 3\).*dimension 2 is 4, expected 3"):
        check_shape(torch.zeros(2, 5, 4), ("B", "N", 3), "points")
    with pytest.raises(ValueError, match="3 dimensions"):
        check_shape(torch.zeros(5, 3), ("B", "N", 3), "points")
    with pytest.raises(ValueError, match="size N is both 2 and 3"):
        check_shape(torch.zeros(2, 3), ("N", "N"), "square")


def test_check_same_leading_reports_conflicts_with_earlier_sizes():
    sizes = {}
    check_same_leading({"points": {"B": 2, "N": 5}}, sizes, "fit")
    with pytest.raises(ValueError, match="size B of normals is 3 but B of another argument is 2"):
        check_same_leading({"normals": {"B": 3}}, sizes, "fit")
    with pytest.raises(ValueError, match="size N of b is 4 but N of a is 5"):
        check_same_leading({"a": {"N": 5}, "b": {"N": 4}}, {}, "pair")


def test_value_checks():
    with pytest.raises(ValueError, match=r"x contains 1 NaN or infinite value\(s\) \(first at index \(1,\)\)"):
        check_finite(torch.tensor([0.0, float("nan")]), "x")
    with pytest.raises(ValueError, match="zero-length"):
        check_unit_vectors(torch.zeros(1, 3), "normals")
    with pytest.raises(ValueError, match="length 2"):
        check_unit_vectors(torch.tensor([[2.0, 0.0, 0.0]]), "normals")
    with pytest.raises(ValueError, match="must be positive"):
        check_positive(torch.tensor([1.0, 0.0]), "s")
    check_positive(torch.tensor([1.0, 0.0]), "s", allow_zero=True)
    check_unit_vectors(torch.tensor([[0.0, 0.6, 0.8]]), "normals")
