"""load_encoder resolution and the weight-free ``pixels`` encoder."""

import numpy as np
import pytest

from rdd.encoders import available_encoders, load_encoder
from rdd.encoders.base import Encoder


def test_unknown_name_lists_available():
    with pytest.raises(ValueError) as err:
        load_encoder("no_such_encoder")
    assert "pixels" in str(err.value)
    assert "no_such_encoder" in str(err.value)


@pytest.mark.parametrize("bad", ["../base", "rdd.encoders.pixels", "Pixels", ""])
def test_invalid_names_rejected(bad):
    with pytest.raises(ValueError):
        load_encoder(bad)


def test_non_encoder_modules_not_listed():
    names = available_encoders()
    assert "pixels" in names
    for helper in ("base", "embed", "cache", "_common"):
        assert helper not in names


def test_pixels_is_block_mean_scaled():
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, size=(3, 32, 32, 3), dtype=np.uint8)
    enc = load_encoder("pixels", size=4, batch_size=2)
    assert isinstance(enc, Encoder)
    assert enc.dim == 3 * 4 * 4
    out = enc.encode(images)
    assert out.dtype == np.float32 and out.shape == (3, 48)
    # Independent expectation: 8x8 block means, channel-first flattening, scaled to [-1, 1].
    blocks = images.astype(np.float64).reshape(3, 4, 8, 4, 8, 3).mean(axis=(2, 4)) / 255.0
    expected = (blocks * 2 - 1).transpose(0, 3, 1, 2).reshape(3, -1)
    np.testing.assert_allclose(out, expected, atol=1e-5)


def test_pixels_rejects_bad_input_and_checkpoint():
    enc = load_encoder("pixels")
    with pytest.raises(ValueError, match="uint8"):
        enc.encode(np.zeros((1, 8, 8, 3), dtype=np.float32))
    with pytest.raises(ValueError, match="N, H, W, 3"):
        enc.encode(np.zeros((8, 8, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="checkpoint"):
        load_encoder("pixels", checkpoint="/tmp/x.pt")
    assert enc.encode(np.zeros((0, 8, 8, 3), dtype=np.uint8)).shape == (0, enc.dim)


def test_pixels_weights_id_depends_on_size():
    assert load_encoder("pixels", size=8).weights_id != load_encoder("pixels", size=16).weights_id
