"""K members' image encoders (rsl-rl ``CNN``s, as ``rl.image_model.ImageModel`` runs them) on their own images,
with kernels and biases that are views of the members' flat parameters: each layer runs as K convolutions of a solo
run's shape (under a CUDA graph their launches cost nothing); one grouped convolution of all K was measured slower,
forward and backward (docs/benchmarks.md)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional

from ...image_model import LOW_PRECISION_DEVICES, ImageModel, to_blocks


@dataclass(frozen=True)
class ConvLayer:
    """One convolution of an encoder: its rsl-rl module name, channels in and out, kernel and stride (pixels)."""

    name: str
    in_channels: int
    out_channels: int
    kernel: tuple[int, int]
    stride: tuple[int, int]

    @property
    def weight_shape(self) -> tuple[int, int, int, int]:
        return (self.out_channels, self.in_channels, *self.kernel)


def encoder_layers(actor: ImageModel) -> tuple[str, list[ConvLayer], nn.Module]:
    """The image group an ``ImageModel`` actor sees alone, its encoder's convolutions and their activation; ValueError
    where its encoder is other than convolutions, each followed by the activation, then a flatten (rsl-rl ``CNN``'s
    default shape)."""
    if len(actor.obs_groups_2d) != 1 or actor.obs_groups:
        raise ValueError(f"a batched image actor sees one image group alone, not {actor.obs_groups_2d} and "
                         f"{actor.obs_groups}")
    group = actor.obs_groups_2d[0]
    modules, layers = list(actor.cnns[group].named_children()), []
    activation = modules[1][1]
    for name, module in modules[:-1]:
        if isinstance(module, nn.Conv2d):
            plain = module.padding == (0, 0) and module.dilation == (1, 1) and module.groups == 1
            if not plain or module.bias is None:
                raise ValueError(f"a batched encoder takes plain convolutions with a bias, not {module}")
            layers.append(ConvLayer(f"cnns.{group}.{name}", module.in_channels, module.out_channels,
                                    module.kernel_size, module.stride))
        elif module is not activation:
            raise ValueError(f"a batched encoder takes convolutions and their activation, not {module}")
    if not isinstance(modules[-1][1], nn.Flatten):
        raise ValueError("a batched encoder's output is flattened (rsl-rl CNN flatten=True)")
    return group, layers, activation


def encode_members(images: torch.Tensor, weights: list[tuple[torch.Tensor, torch.Tensor]], layers: list[ConvLayer],
                   activation: nn.Module, block: int, low_precision: bool) -> torch.Tensor:
    """(K, B, C, H, W) images (uint8 scaled to [0, 1], or float) through each member's encoder, its layers' ``weights``
    [(kernels (K, O C kh kw), biases (K, O))], the first over ``block`` x ``block`` pixel blocks (``to_blocks``); on a
    GPU in bfloat16 where ``low_precision``, channels-last. Returns the flattened float32 features (K, B, F)."""
    device = images.device.type
    low = low_precision and device in LOW_PRECISION_DEVICES
    features = []
    for k, member_images in enumerate(images):
        x = to_blocks(member_images, block, torch.bfloat16 if low else torch.float32, device == "cuda")
        with torch.autocast(device_type=device, dtype=torch.bfloat16, enabled=low):
            for (weight, bias), layer in zip(weights, layers, strict=True):
                x = activation(functional.conv2d(x, weight[k].view(layer.weight_shape), bias[k], stride=layer.stride))
        features.append(x.float().flatten(1))
    return torch.stack(features)
