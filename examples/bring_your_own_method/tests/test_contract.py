"""tissuebench's method contract, run by this package's own tests (tissuebench.testing): one
test per named check, on tissuebench's small built-in trainings; and on a cube whose supports
prescribe a displacement."""
import pytest

from podreg import PodPolyReg
from tissuebench.testing import check_method, parametrize_with_checks


@parametrize_with_checks([PodPolyReg, (PodPolyReg, {"n_modes": 2, "degree": 3})])
def test_tissuebench_contract(method, check):
    check(method)


def test_the_prescribed_stretch_of_a_cube():
    check_method(PodPolyReg, training="prescribed", checks=["reconstruct_is_the_full_field", "steps_inside_are_ok"])


def test_options_are_checked_naming_them():
    with pytest.raises(ValueError, match="degree = -1"):
        PodPolyReg(degree=-1)
    with pytest.raises(ValueError, match="degree = 0"):  # no constant term: degree 0 would be u = 0
        PodPolyReg(degree=0)
