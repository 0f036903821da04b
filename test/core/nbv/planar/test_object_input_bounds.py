"""Object images and masks are bounded by their declared size before decoding; absurd rods are refused."""

import time

import numpy as np
import pytest
from PIL import Image

from agiprobot_measurement.common.limits import LIMITS, InputTooLarge
from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.objects import load_object_file
from agiprobot_measurement.nbv.planar.range_finder import RangeFinder2D


def test_an_image_larger_than_the_limit_is_refused_from_its_header(tmp_path):
    side = int(LIMITS.image_pixels**0.5) + 100
    path = tmp_path / "big.png"
    im = Image.new("1", (side, side), 1)
    im.paste(0, (10, 10, 20, 20))
    im.save(path)
    t0 = time.perf_counter()
    with pytest.raises(InputTooLarge, match="more than the limit"):
        load_object_file(path)
    assert time.perf_counter() - t0 < 5.0


def test_a_mask_whose_header_claims_a_huge_array_is_refused_before_loading(tmp_path):
    path = tmp_path / "huge.npy"
    header = np.lib.format.header_data_from_array_1_0(np.zeros((1, 1)))
    header["shape"] = (200_000, 200_000)
    with path.open("wb") as f:
        np.lib.format.write_array_header_1_0(f, header)
        f.write(b"\0" * 100)
    with pytest.raises(InputTooLarge, match="200000 x 200000"):
        load_object_file(path)


def test_a_small_image_still_loads(tmp_path):
    path = tmp_path / "ok.png"
    im = Image.new("RGB", (40, 30), (255, 255, 255))
    im.paste((0, 0, 0), (10, 10, 20, 20))
    im.save(path)
    body = load_object_file(path)
    assert body.shape == (40, 30) and int((body > 0).sum()) == 100


@pytest.mark.parametrize("length", [1e308, 1e6])
def test_an_absurd_rod_length_is_a_clear_error(length):
    rf = RangeFinder2D.from_config()
    with pytest.raises(NbvInputError, match="RFlength"):
        rf.with_length(length)
