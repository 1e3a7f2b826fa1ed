"""A tiny in-memory stand-in for the label-shard dataset: learnable, seeded, picklable."""

import torch
from torch.utils.data import Dataset


class FakeHazardDataset(Dataset):
    """``n`` samples of ``{"image": (1, size, size) float32 in [0, 1], "mask": (size, size) int64}``.

    The mask is safe (1) where the image is below 0.5, unsafe (0) elsewhere, 255 on a 2-pixel border.
    """

    def __init__(self, n: int = 8, size: int = 32, seed: int = 0) -> None:
        gen = torch.Generator().manual_seed(seed)
        coarse = torch.rand(n, 1, size // 8, size // 8, generator=gen)
        self.images = torch.nn.functional.interpolate(coarse, size=(size, size), mode="bilinear", align_corners=False)
        self.masks = (self.images[:, 0] < 0.5).long()
        self.masks[:, :2, :] = 255
        self.masks[:, -2:, :] = 255
        self.masks[:, :, :2] = 255
        self.masks[:, :, -2:] = 255

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {"image": self.images[i].clone(), "mask": self.masks[i].clone()}
