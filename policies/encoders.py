"""Image encoders for visuomotor policies, trained from scratch (no weights are downloaded).

Two backbones, each ending in spatial-softmax keypoints (Levine et al. 2016; the Diffusion Policy,
robomimic and LeRobot image design):

- ``resnet18``: ResNet-18's layout (7x7 stem, max-pool, four stages of two basic blocks, 64-512
  channels) with GroupNorm in place of BatchNorm. BatchNorm's running statistics drift between the
  random crops of training and the centre crop of evaluation, and with EMA weights; GroupNorm has
  none (Chi et al. 2023 replace it for that reason). About 11 M parameters: a GPU encoder.
- ``small``: four 3x3 convolutions (16-64 channels, two of stride 2) with GroupNorm, ~40 k
  parameters and ~9 M multiply-adds per 56x56 crop, sized for training on a laptop CPU in minutes.

:class:`SpatialSoftmax` turns the last feature map ``[C, h, w]`` into ``K`` keypoints: a 1x1
convolution to ``K`` maps, a softmax over each map's pixels, and the expected pixel coordinate
under it, in [-1, 1] (x to the right, y down the image). Keypoints say *where* something is, which
is what a manipulation policy needs from an image, and keep the feature count small.

:class:`CropAugment` takes a random ``crop x crop`` window per image in training (different for
every sample) and the centre window in evaluation (``module.eval()``), as Diffusion Policy does.

Images enter as uint8 ``[N, H, W, 3]`` (the store's layout) and are scaled to [0, 1] on the device
the encoder lives on, so only bytes cross from host memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

BACKBONES = ("small", "resnet18")


@dataclass
class EncoderConfig:
    """How camera images become features (``demo train --encoder``, ``--crop``, ``--color-jitter``)."""

    backbone: str = "small"  # small (CPU) | resnet18 (GroupNorm ResNet-18, a GPU encoder)
    crop: float = 0.875  # random crop side as a fraction of the image side (DP: 84 of 96); 1 = no crop
    # Colour jitter in training (0 = off): brightness shifted by up to j, contrast and saturation scaled by
    # 1 +- j, per image; against lighting and colour shifts (demo eval --shift lighting|texture)
    color_jitter: float = 0.0
    keypoints: int = 32  # spatial-softmax keypoints per camera (2 features each)
    features: int = 64  # features per camera after a linear layer over the keypoints
    # With an auxiliary target (demo train --aux-target): the weight of its loss, the mean squared error of the
    # state (normalised to [-1, 1]) predicted linearly from the cameras' features, beside the action loss
    aux_weight: float = 1.0

    def __post_init__(self) -> None:
        if self.backbone not in BACKBONES:
            raise ValueError(f"encoder backbone {self.backbone!r} is not one of {', '.join(BACKBONES)}")
        if not 0.25 <= float(self.crop) <= 1.0:
            raise ValueError(f"crop must lie in [0.25, 1], got {self.crop}")
        if self.keypoints < 1 or self.features < 1:
            raise ValueError("keypoints and features must be positive")
        if not 0.0 <= float(self.color_jitter) <= 1.0:
            raise ValueError(f"color_jitter must lie in [0, 1], got {self.color_jitter}")
        if float(self.aux_weight) < 0:
            raise ValueError(f"aux_weight must be at least 0, got {self.aux_weight}")
        self.crop = float(self.crop)
        self.aux_weight = float(self.aux_weight)
        self.color_jitter = float(self.color_jitter)

    def crop_size(self, height: int, width: int) -> tuple[int, int]:
        """Crop window (height, width) in pixels for an image of ``height x width``."""
        return min(height, max(8, round(self.crop * height))), min(width, max(8, round(self.crop * width)))


def _groups(channels: int) -> int:
    return max(1, channels // 16)  # 16 channels per group, as Diffusion Policy's replacement does


class SpatialSoftmax(nn.Module):
    """``[N, C, h, w]`` -> ``[N, 2K]``: the expected (x, y) in [-1, 1] of each of ``K`` softmax maps."""

    def __init__(self, channels: int, height: int, width: int, keypoints: int):
        super().__init__()
        self.keypoints = nn.Conv2d(channels, keypoints, kernel_size=1)
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, height), torch.linspace(-1, 1, width), indexing="ij")
        self.register_buffer("grid", torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=1), persistent=False)  # [h*w, 2]

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        maps = self.keypoints(features).flatten(2)  # [N, K, h*w]
        attention = torch.softmax(maps.float(), dim=-1).to(self.grid.dtype)
        return (attention @ self.grid).flatten(1)  # [N, K * 2]


class BasicBlock(nn.Module):
    """ResNet's two 3x3 convolutions with a skip connection, GroupNorm instead of BatchNorm."""

    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.norm1 = nn.GroupNorm(_groups(cout), cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.norm2 = nn.GroupNorm(_groups(cout), cout)
        self.skip = nn.Identity() if stride == 1 and cin == cout else nn.Sequential(
            nn.Conv2d(cin, cout, 1, stride, bias=False), nn.GroupNorm(_groups(cout), cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        return F.relu(self.norm2(self.conv2(y)) + self.skip(x))


def resnet18_gn() -> nn.Sequential:
    """ResNet-18 without its pooling and classifier: ``[N, 3, H, W]`` -> ``[N, 512, H/32, W/32]``."""
    layers: list[nn.Module] = [nn.Conv2d(3, 64, 7, 2, 3, bias=False), nn.GroupNorm(_groups(64), 64), nn.ReLU(),
                               nn.MaxPool2d(3, 2, 1)]
    cin = 64
    for cout, stride in ((64, 1), (128, 2), (256, 2), (512, 2)):
        layers += [BasicBlock(cin, cout, stride), BasicBlock(cout, cout, 1)]
        cin = cout
    return nn.Sequential(*layers)


def small_cnn() -> nn.Sequential:
    """Four 3x3 convolutions: ``[N, 3, H, W]`` -> ``[N, 64, H/4, W/4]`` (~40 k parameters)."""
    def conv(cin: int, cout: int, stride: int) -> list[nn.Module]:
        return [nn.Conv2d(cin, cout, 3, stride, 1), nn.GroupNorm(_groups(cout), cout), nn.ReLU()]

    return nn.Sequential(*conv(3, 16, 2), *conv(16, 32, 1), *conv(32, 32, 2), *conv(32, 64, 1))


class CropAugment(nn.Module):
    """Random ``crop`` windows per image in training, the centre window in evaluation."""

    def __init__(self, height: int, width: int, crop: tuple[int, int]):
        super().__init__()
        self.height, self.width = height, width
        self.crop = crop

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """``[N, C, H, W]`` -> ``[N, C, ch, cw]``."""
        ch, cw = self.crop
        if (ch, cw) == (self.height, self.width):
            return images
        if not self.training:
            top, left = (self.height - ch) // 2, (self.width - cw) // 2
            return images[:, :, top : top + ch, left : left + cw]
        n = images.shape[0]
        top = torch.randint(0, self.height - ch + 1, (n, 1, 1), device=images.device)
        left = torch.randint(0, self.width - cw + 1, (n, 1, 1), device=images.device)
        rows = (top + torch.arange(ch, device=images.device).view(1, ch, 1)).expand(n, ch, cw)
        cols = (left + torch.arange(cw, device=images.device).view(1, 1, cw)).expand(n, ch, cw)
        flat = (rows * self.width + cols).reshape(n, 1, ch * cw).expand(n, images.shape[1], ch * cw)
        return images.flatten(2).gather(2, flat).reshape(n, images.shape[1], ch, cw)


class ColorJitter(nn.Module):
    """Per image in training, on pixels in [-1, 1]: brightness + U(-j, j), contrast and saturation x U(1 - j,
    1 + j) about the image's mean and each pixel's grey; nothing in evaluation."""

    def __init__(self, strength: float):
        super().__init__()
        self.strength = strength

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """``[N, 3, H, W]`` -> the same, jittered (clipped to [-1, 1])."""
        j = self.strength
        if not self.training or j == 0:
            return images
        n = images.shape[0]

        def draw(low: float, high: float) -> torch.Tensor:
            return torch.empty(n, 1, 1, 1, device=images.device).uniform_(low, high)

        grey = images.mean(dim=1, keepdim=True)
        x = grey + (images - grey) * draw(1 - j, 1 + j)  # saturation
        mean = x.mean(dim=(1, 2, 3), keepdim=True)
        x = mean + (x - mean) * draw(1 - j, 1 + j)  # contrast
        return (x + draw(-j, j)).clamp_(-1.0, 1.0)  # brightness


class CameraEncoder(nn.Module):
    """One camera's uint8 images ``[N, H, W, 3]`` -> features ``[N, features]``.

    ``cond_dim`` > 0: FiLM (RT-1's conditioning of its image encoder) of the backbone's feature maps by a
    condition vector (an instruction's): each channel scaled by ``1 + gamma`` and shifted by ``beta``, both
    linear in the condition and zero at initialisation, before the keypoints are found, so the words can
    select what the camera attends to."""

    def __init__(self, height: int, width: int, config: EncoderConfig, cond_dim: int = 0):
        super().__init__()
        crop = config.crop_size(height, width)
        self.jitter = ColorJitter(config.color_jitter)
        self.augment = CropAugment(height, width, crop)
        self.backbone = resnet18_gn() if config.backbone == "resnet18" else small_cnn()
        with torch.no_grad():
            c, h, w = self.backbone(torch.zeros(1, 3, *crop)).shape[1:]
        self.keypoints = SpatialSoftmax(c, h, w, config.keypoints)
        self.out = nn.Sequential(nn.Linear(2 * config.keypoints, config.features), nn.LayerNorm(config.features), nn.ReLU())
        self.film = nn.Linear(cond_dim, 2 * c) if cond_dim else None
        if self.film is not None:  # identity at initialisation: the condition's effect is learnt
            nn.init.zeros_(self.film.weight)
            nn.init.zeros_(self.film.bias)

    def preprocess(self, images: torch.Tensor) -> torch.Tensor:
        """uint8 ``[N, H, W, 3]`` -> the backbone's input: floats in [-1, 1], ``[N, 3, ch, cw]``, cropped."""
        return self.augment(self.jitter(images.permute(0, 3, 1, 2).float().div_(127.5).sub_(1.0)))

    def features(self, x: torch.Tensor, condition: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`preprocess`'s output (and ``[N, cond_dim]`` conditions with FiLM) -> ``[N, features]``."""
        maps = self.backbone(x)
        if self.film is not None and condition is not None:
            gamma, beta = self.film(condition.to(maps.dtype)).chunk(2, dim=-1)
            maps = maps * (1.0 + gamma[..., None, None]) + beta[..., None, None]
        return self.out(self.keypoints(maps))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.features(self.preprocess(images))
