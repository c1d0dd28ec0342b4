"""``ImageModel``: rsl-rl's ``CNNModel`` on camera observations as the env stores them (uint8 colour, scaled to [0, 1]
inside the network, or float32 depth in metres): a uint8 rollout takes a quarter of the memory of a float one. Its
exports take those images and give the deterministic actions."""

from __future__ import annotations

import copy

import torch
from rsl_rl.models import CNNModel
from tensordict import TensorDict
from torch import nn


def unit_scale(images: torch.Tensor) -> torch.Tensor:
    """uint8 pixels as floats in [0, 1]; float images (depth in metres) as they are."""
    return images.float() / 255.0 if images.dtype == torch.uint8 else images


class ImageModel(CNNModel):
    """``CNNModel`` whose image groups may be uint8."""

    def __init__(self, obs: TensorDict, obs_groups: dict[str, list[str]], obs_set: str, output_dim: int, **kwargs):
        super().__init__(obs, obs_groups, obs_set, output_dim, **kwargs)
        self.image_dtypes = [obs[group].dtype for group in self.obs_groups_2d]

    def get_latent(self, obs: TensorDict, masks: torch.Tensor | None = None, hidden_state=None) -> torch.Tensor:
        scaled = obs.copy()
        for group in self.obs_groups_2d:
            scaled[group] = unit_scale(obs[group])
        return super().get_latent(scaled, masks, hidden_state)

    def update_normalization(self, obs: TensorDict) -> None:
        """Update the state observations' statistics (``obs_normalization``; images are not normalised this way), if
        the model sees any."""
        if self.obs_groups:
            super().update_normalization(obs)

    def as_jit(self) -> nn.Module:
        return ExportedImageActor(self)

    def as_onnx(self, verbose: bool = False) -> nn.Module:
        return ExportedImageActor(self)


class ExportedImageActor(nn.Module):
    """The deterministic actor of an ``ImageModel`` that sees one image group and nothing else (the env's camera
    observations): ``forward(obs)`` with obs (N, C, H, W) as the env gives it -> actions (N, num_actions); TorchScript
    and ONNX export it as it is."""

    def __init__(self, model: ImageModel):
        super().__init__()
        if len(model.obs_groups_2d) != 1 or model.obs_groups:
            raise ValueError(f"exports an actor that sees one image group alone; this one sees {model.obs_groups_2d} "
                             f"and {model.obs_groups}")
        group = model.obs_groups_2d[0]
        self.cnn = copy.deepcopy(model.cnns[group])
        self.mlp = copy.deepcopy(model.mlp)
        self.deterministic_output = (model.distribution.as_deterministic_output_module()
                                     if model.distribution is not None else nn.Identity())
        self.input_shape = (int(model.obs_channels_2d[0]), *(int(size) for size in model.obs_dims_2d[0]))
        self.input_dtype = model.image_dtypes[0]

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.deterministic_output(self.mlp(self.cnn(unit_scale(obs))))

    @torch.jit.export
    def reset(self) -> None:
        """Nothing to reset (rsl-rl's exports have it for recurrent actors)."""

    def get_dummy_inputs(self) -> tuple[torch.Tensor]:
        return (torch.zeros(1, *self.input_shape, dtype=self.input_dtype),)

    @property
    @torch.jit.unused
    def input_names(self) -> list[str]:
        return ["obs"]

    @property
    @torch.jit.unused
    def output_names(self) -> list[str]:
        return ["actions"]
