"""Image encoders: spatial-softmax keypoints, crop augmentation, both backbones' shapes."""

from __future__ import annotations

import pytest
import torch

from demo.policies.encoders import (CameraEncoder, ColorJitter, CropAugment, EncoderConfig, SpatialSoftmax, resnet18_gn,
                                    small_cnn)


def test_spatial_softmax_finds_a_bright_pixel() -> None:
    layer = SpatialSoftmax(1, 5, 9, keypoints=1)
    with torch.no_grad():
        layer.keypoints.weight.fill_(1.0)
        layer.keypoints.bias.zero_()
    maps = torch.zeros(1, 1, 5, 9)
    maps[0, 0, 4, 2] = 100.0  # bottom row, third column
    x, y = layer(maps)[0].tolist()
    assert x == pytest.approx(-1 + 2 * 2 / 8, abs=1e-4) and y == pytest.approx(1.0, abs=1e-4)


def test_crops_are_random_per_image_in_training_and_central_in_evaluation() -> None:
    images = torch.arange(16 * 16, dtype=torch.float32).reshape(1, 1, 16, 16).repeat(64, 3, 1, 1)
    crop = CropAugment(16, 16, (12, 12))
    torch.manual_seed(0)
    out = crop.train()(images)
    assert out.shape == (64, 3, 12, 12)
    corners = out[:, 0, 0, 0]
    assert len(set(corners.tolist())) > 10  # different windows for different samples
    for i in range(64):  # every crop is a real window of the image, channels aligned
        r, c = divmod(int(corners[i]), 16)
        assert torch.equal(out[i], images[i, :, r : r + 12, c : c + 12])
    assert torch.equal(crop.eval()(images), images[:, :, 2:14, 2:14])


@pytest.mark.parametrize("backbone, channels", [("small", 64), ("resnet18", 512)])
def test_backbones_and_camera_encoder_shapes(backbone: str, channels: int) -> None:
    net = small_cnn() if backbone == "small" else resnet18_gn()
    assert net(torch.zeros(2, 3, 64, 64)).shape[1] == channels
    encoder = CameraEncoder(72, 96, EncoderConfig(backbone=backbone, keypoints=8, features=20))
    features = encoder(torch.randint(0, 256, (3, 72, 96, 3), dtype=torch.uint8))
    assert features.shape == (3, 20) and torch.isfinite(features).all()
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in encoder.modules())  # GroupNorm only


def test_config_is_checked() -> None:
    with pytest.raises(ValueError, match="backbone"):
        EncoderConfig(backbone="vgg")
    with pytest.raises(ValueError, match="crop"):
        EncoderConfig(crop=1.5)
    with pytest.raises(ValueError, match="color_jitter"):
        EncoderConfig(color_jitter=2.0)
    assert EncoderConfig(crop=0.875).crop_size(64, 64) == (56, 56)
    assert EncoderConfig().crop_size(4, 4) == (4, 4)  # never larger than the image


def test_colour_jitter_varies_images_in_training_only() -> None:
    torch.manual_seed(0)
    images = torch.rand(8, 3, 16, 16) * 1.6 - 0.8
    jitter = ColorJitter(0.3)
    out = jitter.train()(images)
    assert out.shape == images.shape and out.min() >= -1 and out.max() <= 1
    shift = (out - images).mean(dim=(1, 2, 3))
    assert shift.std() > 0.02  # per image, not one change for the batch
    assert torch.equal(jitter.eval()(images), images)
    assert torch.equal(ColorJitter(0.0).train()(images), images)
