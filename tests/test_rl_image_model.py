"""The pixel policy's encoder (``rl.image_model``): its first convolution over pixel blocks computes what rsl-rl's own
``CNNModel`` computes with the same kernel; the GPU's channels-last gather holds the same numbers as the plain one;
the bfloat16 update lands close to the float32 one; the gradient all-reduce takes channels-last kernels."""

import copy
import os
from types import SimpleNamespace

import pytest
import torch
from conftest import collect
from rsl_rl.models import CNNModel
from tensordict import TensorDict
from torch import nn

import cartpole_warp
from cartpole_warp.rl import image_model
from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.image_model import ImageModel, stack_blocks, to_blocks
from cartpole_warp.rl.learners.ppo.sync_free import SyncFreePPO
from cartpole_warp.rl.loop import TrainingLoop
from cartpole_warp.rl.policies import to_rsl_rl
from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv

GROUPS = {"actor": ["policy"], "critic": ["critic"]}


def actor_settings(**cnn):
    cfg = train_config("cartpole-balance-rgb")
    actor = to_rsl_rl(cfg.agent, images=True)["actor"]
    actor["cnn_cfg"] |= cnn
    return {key: value for key, value in actor.items() if key not in ("class_name", "precision")}


@pytest.mark.parametrize(("shape", "dtype", "cnn", "block"), [
    ((9, 64, 64), torch.uint8, {}, 4),  # the pixel tasks' colour frames and encoder
    ((3, 64, 64), torch.float32, {}, 4),  # depth in metres
    ((9, 32, 48), torch.uint8, {"kernel_size": [4, 4, 3], "stride": [2, 2, 1]}, 2),
    ((9, 30, 30), torch.uint8, {"kernel_size": [3, 3, 3], "stride": [2, 2, 1]}, 1),  # 3 does not divide by 2
])
def test_the_blocked_encoder_computes_rsl_rl_cnn_model(shape, dtype, cnn, block):
    torch.manual_seed(0)
    n = 6
    frames = (torch.randint(0, 256, (n, *shape), dtype=torch.uint8) if dtype == torch.uint8
              else torch.rand(n, *shape) * 8.0)
    obs = TensorDict({"policy": frames, "critic": torch.randn(n, 4)}, batch_size=[n])
    settings = actor_settings(**cnn)
    floats = frames.float() / 255.0 if dtype == torch.uint8 else frames
    reference = CNNModel(TensorDict({"policy": floats, "critic": obs["critic"]}, batch_size=[n]), GROUPS, "actor", 1,
                         **settings)
    ours = ImageModel(obs, GROUPS, "actor", 1, **settings)
    assert ours.blocks == {"policy": block}
    assert ours.cnns["policy"][0].in_channels == shape[0] * block * block
    ours.load_state_dict(reference.state_dict())  # rsl-rl's kernel, rewritten for the blocks
    expected = reference(TensorDict({"policy": floats, "critic": obs["critic"]}, batch_size=[n]))
    torch.testing.assert_close(ours(obs), expected, rtol=1e-5, atol=1e-6)
    exported = image_model.ExportedImageActor(ours)
    torch.testing.assert_close(exported(frames), expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("block", [1, 2, 4])
@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32])
def test_the_channels_last_gather_holds_the_plain_blocks(block, dtype):
    torch.manual_seed(1)
    frames = (torch.randint(0, 256, (5, 9, 32, 64), dtype=torch.uint8) if dtype == torch.uint8
              else torch.rand(5, 3, 32, 64))
    plain = stack_blocks(frames, block)
    for images in (frames, frames[:, :, :, :].transpose(2, 3).contiguous().transpose(2, 3)):  # contiguous or not
        gathered = to_blocks(images, block, torch.float32, channels_last=True)
        assert gathered.is_contiguous(memory_format=torch.channels_last)
        assert torch.equal(gathered, plain)
    assert to_blocks(frames, block, torch.bfloat16, channels_last=True).dtype == torch.bfloat16


def pixel_runner(precision):
    cfg = train_config("cartpole-balance-rgb")
    cfg.agent.actor.cnn.precision = precision
    cfg.env.num_envs = 16
    torch.manual_seed(0)
    return TrainingLoop(RslRlVecEnv(cartpole_warp.tasks.make("cartpole-balance-rgb", num_envs=16, seed=3)), cfg, None)


def test_the_bfloat16_update_lands_within_a_few_percent_of_the_float32_one(monkeypatch):
    """The same rollout and mini-batches, one update in float32 and one with the encoder in bfloat16 (on the CPU here:
    the GPU's path is the same autocast, on channels-last tensors): every parameter's step agrees within 5% of its
    size, where a mis-scaled input or a lost gradient would differ by the whole step."""
    monkeypatch.setattr(image_model, "LOW_PRECISION_DEVICES", ("cuda", "cpu"))
    exact, low = pixel_runner("float32"), pixel_runner("bfloat16")
    low.learner.alg.actor.load_state_dict(exact.learner.alg.actor.state_dict())
    low.learner.alg.critic.load_state_dict(exact.learner.alg.critic.state_dict())
    before = copy.deepcopy(exact.learner.alg.actor.state_dict())
    obs = collect(exact)
    low.learner.alg.storage = copy.deepcopy(exact.learner.alg.storage)
    with torch.inference_mode():
        features = low.learner.alg.actor.encode("policy", obs["policy"])
        unchanged = torch.equal(features, exact.learner.alg.actor.encode("policy", obs["policy"]))
        assert not unchanged, "bfloat16 was not used"
    for runner in (exact, low):
        torch.manual_seed(2)
        runner.learner.alg.update()
    for name, start in before.items():
        step_exact = exact.learner.alg.actor.state_dict()[name] - start
        step_low = low.learner.alg.actor.state_dict()[name] - start
        if step_exact.abs().max() > 0:
            assert (step_low - step_exact).norm() <= 0.05 * step_exact.norm(), name


def _reduce(rank, store, results):
    torch.distributed.init_process_group("gloo", store=torch.distributed.FileStore(store, 2), rank=rank, world_size=2)
    conv = nn.Conv2d(144, 16, 2).to(memory_format=torch.channels_last)
    conv.weight.grad = torch.full_like(conv.weight, rank + 1.0)  # laid out like the kernel: channels-last
    critic = nn.Linear(4, 1)
    critic.weight.grad = torch.full_like(critic.weight, 10.0 * (rank + 1))
    alg = SimpleNamespace(actor=conv, critic=critic, gpu_world_size=2, grad_reduce_bucket_mb=25)
    SyncFreePPO.reduce_parameters(alg)
    results[rank] = (conv.weight.grad.unique().tolist(), critic.weight.grad.unique().tolist())
    torch.distributed.destroy_process_group()


def test_the_gradient_all_reduce_averages_channels_last_kernels(tmp_path):
    assert not nn.Conv2d(144, 16, 2).to(memory_format=torch.channels_last).weight.is_contiguous()
    results = torch.multiprocessing.Manager().dict()
    os.environ.pop("WORLD_SIZE", None)
    torch.multiprocessing.spawn(_reduce, args=(str(tmp_path / "store"), results), nprocs=2)
    assert results[0] == results[1] == ([1.5], [15.0])
