"""``ImageModel``: rsl-rl's ``CNNModel`` on camera observations as the env stores them (uint8 colour, scaled to [0, 1]
inside the network, or float32 depth in metres): a uint8 rollout takes a quarter of the memory of a float one.

Its first convolution (kernel k, stride s) runs as the same convolution rewritten: a stride-1 convolution of kernel
k/s over the image's s x s blocks of pixels stacked as channels (space-to-depth), where k and the image's sides divide
by s; 9 channels of three colour frames become 144, a shape the GPU's matrix units take without padding (its
checkpoints store that kernel; an rsl-rl ``CNN`` kernel of the first shape loads and is rewritten). On a GPU the
encoder computes in bfloat16 (``precision``) on channels-last tensors; the MLP after it, the losses and the weights
stay float32. Its exports take the images and give the deterministic actions (float32 throughout)."""

from __future__ import annotations

import copy

import torch
from rsl_rl.models import CNNModel
from rsl_rl.utils import get_param
from tensordict import TensorDict
from torch import nn

LOW_PRECISION_DEVICES = ("cuda",)
"""Device types where ``precision='bfloat16'`` applies (a CPU's bfloat16 convolutions are slower than its float32
ones); elsewhere the encoder computes in float32."""


BLOCK_ROW_WORDS = {2: torch.int16, 4: torch.int32, 8: torch.int64}
"""A block's row of uint8 pixels as one integer word: the gather moves a quarter (block 4) of the elements."""


def unit_scale(images: torch.Tensor) -> torch.Tensor:
    """uint8 pixels as floats in [0, 1]; float images (depth in metres) as they are."""
    return images.float() / 255.0 if images.dtype == torch.uint8 else images


def block_size(cnn_cfg: dict, height: int, width: int) -> int:
    """The side of the pixel blocks that the first convolution can run over (its stride, where its kernel and the
    image's sides divide by it, with no padding or dilation), else 1."""
    kernel, stride = get_param(cnn_cfg["kernel_size"], 0), get_param(cnn_cfg.get("stride", 1), 0)
    plain = cnn_cfg.get("padding", "none") == "none" and get_param(cnn_cfg.get("dilation", 1), 0) == 1
    fits = stride > 1 and kernel % stride == 0 and height % stride == 0 and width % stride == 0
    return stride if plain and fits else 1


def on_blocks(cnn_cfg: dict, block: int) -> dict:
    """``cnn_cfg`` with its first convolution over ``block`` x ``block`` blocks (kernel / block, stride 1)."""
    layers = range(len(cnn_cfg["output_channels"]))
    kernel = [get_param(cnn_cfg["kernel_size"], i) for i in layers]
    stride = [get_param(cnn_cfg.get("stride", 1), i) for i in layers]
    kernel[0], stride[0] = kernel[0] // block, 1
    return cnn_cfg | {"kernel_size": kernel, "stride": stride}


def stack_blocks(images: torch.Tensor, block: int) -> torch.Tensor:
    """(N, C, H, W) images as float32 (N, C x block^2, H / block, W / block) (uint8 scaled to [0, 1]), channel
    c x block^2 + i x block + j holding pixel (i, j) of each block of channel c: reshapes that an export traces."""
    _, c, h, w = images.shape
    blocks = images.reshape(-1, c, h // block, block, w // block, block).permute(0, 1, 3, 5, 2, 4)
    return unit_scale(blocks.reshape(-1, c * block * block, h // block, w // block))


def to_blocks(images: torch.Tensor, block: int, dtype: torch.dtype, channels_last: bool) -> torch.Tensor:
    """``stack_blocks`` of ``dtype``; channels-last: one gather of the images into that layout (of whole block rows
    where the pixels are bytes), then one cast."""
    if not channels_last:
        return stack_blocks(images, block).to(dtype)
    _, c, h, w = images.shape
    if images.dtype == torch.uint8 and block in BLOCK_ROW_WORDS and images.is_contiguous():
        rows = images.view(BLOCK_ROW_WORDS[block]).reshape(-1, c, h // block, block, w // block)
        gathered = rows.permute(0, 2, 4, 1, 3).contiguous().view(torch.uint8)
        out = torch.div(gathered, 255.0, out=torch.empty(gathered.shape, dtype=dtype, device=images.device))
    else:
        blocks = images.reshape(-1, c, h // block, block, w // block, block)
        out = torch.empty((images.shape[0], h // block, w // block, c, block, block), dtype=dtype,
                          device=images.device)
        out.copy_(blocks.permute(0, 2, 4, 1, 3, 5))
        if images.dtype == torch.uint8:
            out.div_(255.0)
    return out.view(-1, h // block, w // block, c * block * block).permute(0, 3, 1, 2)


def blocked_kernel(weight: torch.Tensor, block: int) -> torch.Tensor:
    """A convolution kernel (O, C, k, k) rewritten for ``to_blocks`` images: (O, C x block^2, k / block, k / block)."""
    o, c, kh, kw = weight.shape
    return (weight.reshape(o, c, kh // block, block, kw // block, block).permute(0, 1, 3, 5, 2, 4)
            .reshape(o, c * block * block, kh // block, kw // block))


class ImageModel(CNNModel):
    """``CNNModel`` whose image groups may be uint8, its first convolution over pixel blocks, its encoder in
    ``precision`` on a GPU."""

    def __init__(self, obs: TensorDict, obs_groups: dict[str, list[str]], obs_set: str, output_dim: int,
                 precision: str = "float32", cnn_cfg: dict | None = None, **kwargs):
        self.channels_last = True
        """On a GPU, keep the encoders' weights and inputs channels-last (NHWC)."""
        images = [group for group in obs_groups[obs_set] if obs[group].dim() == 4]
        self.image_shapes = {group: tuple(obs[group].shape[1:]) for group in images}
        self.image_dtypes = [obs[group].dtype for group in images]
        per_group = cnn_cfg if cnn_cfg and all(isinstance(v, dict) for v in cnn_cfg.values()) else None
        groups = obs.keys()  # a TensorDict iterates over its rows, not its keys
        self.blocks, blocked_cfg, shapes = {}, {}, {group: obs[group] for group in groups}
        for group in images:
            cfg = per_group[group] if per_group else cnn_cfg
            c, h, w = self.image_shapes[group]
            b = self.blocks[group] = block_size(cfg, h, w)
            blocked_cfg[group] = on_blocks(cfg, b) if b > 1 else cfg
            shapes[group] = torch.empty((1, c * b * b, h // b, w // b), device="meta")
        super().__init__(shapes, obs_groups, obs_set, output_dim, cnn_cfg=blocked_cfg, **kwargs)
        self.low_precision = precision == "bfloat16"
        """Run the encoders in bfloat16 where the device type is in ``LOW_PRECISION_DEVICES``."""
        self._register_load_state_dict_pre_hook(self._blocked_kernels)

    def _blocked_kernels(self, state_dict: dict, prefix: str, *args):
        """Rewrite a first-convolution kernel of the images' own shape (an rsl-rl ``CNN``'s) for the blocks."""
        for group, block in self.blocks.items():
            key = f"{prefix}cnns.{group}.0.weight"
            expected = self.cnns[group][0].weight.shape
            if block > 1 and key in state_dict and state_dict[key].shape[1] * block * block == expected[1]:
                state_dict[key] = blocked_kernel(state_dict[key], block)

    def _apply(self, fn, recurse: bool = True):
        """``nn.Module._apply`` (``to``, ``cuda``, ...); on a GPU the encoders' weights then lie channels-last."""
        module = super()._apply(fn, recurse)
        for cnn in getattr(self, "cnns", {}).values():
            weight = next(cnn.parameters(), None)
            if self.channels_last and weight is not None and weight.device.type == "cuda":
                cnn.to(memory_format=torch.channels_last)
        return module

    def encode(self, group: str, images: torch.Tensor) -> torch.Tensor:
        """The flattened float32 features of one image group's encoder."""
        device = images.device.type
        low = self.low_precision and device in LOW_PRECISION_DEVICES
        blocks = to_blocks(images, self.blocks[group], torch.bfloat16 if low else torch.float32,
                           self.channels_last and device == "cuda")
        with torch.autocast(device_type=device, dtype=torch.bfloat16, enabled=low):
            return self.cnns[group](blocks).float()

    def get_latent(self, obs: TensorDict, masks: torch.Tensor | None = None, hidden_state=None) -> torch.Tensor:
        latent = torch.cat([self.encode(group, obs[group]) for group in self.obs_groups_2d], dim=-1)
        if not self.obs_groups:
            return latent
        return torch.cat([super(CNNModel, self).get_latent(obs), latent], dim=-1)

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
        self.block = model.blocks[group]
        self.input_shape = model.image_shapes[group]
        self.input_dtype = model.image_dtypes[0]

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        images = stack_blocks(obs, self.block)
        return self.deterministic_output(self.mlp(self.cnn(images)))

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
