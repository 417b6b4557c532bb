"""Byte layout of the 32-byte matching descriptor and the 16-byte refinement descriptor (spec §5, §6)."""

import numpy as np

from expoctl.features.viso.descriptors import descriptors, refinement_descriptor


def _coordinate_gradients():
    yy, xx = np.mgrid[0:20, 0:20]
    return xx.astype(np.uint8), (100 + yy).astype(np.uint8)  # du encodes x, dv encodes y


def test_descriptor_byte_layout():
    du, dv = _coordinate_gradients()
    d = descriptors(du, dv, np.array([10]), np.array([10]))
    assert d.shape == (1, 32) and d.dtype == np.uint8
    expected = [
        7, 109, 7, 111, 9, 109, 9, 111, 13, 109, 13, 111, 11, 109, 11, 111,
        9, 105, 9, 115, 11, 105, 11, 115, 5, 107, 5, 113, 15, 107, 15, 113,
    ]  # fmt: skip
    assert d[0].tolist() == expected


def test_descriptors_of_several_features_are_independent_rows():
    du, dv = _coordinate_gradients()
    d = descriptors(du, dv, np.array([10, 12]), np.array([10, 11]))
    assert d[1, 0] == 12 - 3 and d[1, 1] == 100 + 11 - 1


def test_refinement_descriptor_layout():
    du, dv = _coordinate_gradients()
    r = refinement_descriptor(du, dv, 10, 10)
    assert r.tolist() == [10, 8, 10, 12, 9, 10, 10, 11, 8, 10, 12, 10, 109, 110, 110, 111]
