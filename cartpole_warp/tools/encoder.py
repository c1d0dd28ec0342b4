"""What a pixel policy's encoder costs, by arithmetic and memory layout: the actor of a task's training settings
(``rl.image_model.ImageModel``) on random camera frames of the task's shape, timed for the rollout's forward pass
(``--num-envs`` frames) and for one mini-batch's gradient step (forward, PPO-shaped loss, backward, Adam) per variant:
bfloat16 or float32, channels-last or not, cuDNN's algorithm search on or off.

    python -m cartpole_warp.tools.encoder --device cuda:0 --task cartpole-balance-rgb
    python -m cartpole_warp.tools.encoder --device cuda:0 --task cartpole-balance-rgb \\
        --agent.actor.cnn.output-channels 32 64 64

Flags after ``--device`` and ``--num-envs`` are train.py's (they pick the task, its camera and its networks). Times
are medians of CUDA-event timed repeats after warm-up, op by op (training captures both in CUDA graphs, which removes
their launch gaps).
"""

from __future__ import annotations

import itertools
import statistics
import sys

import torch
from tensordict import TensorDict

from ..cli import clean_errors, quiet_libraries
from ..engine.scene import StageError
from ..rl.image_model import ImageModel
from ..rl.policies import to_rsl_rl
from ..rl.runs import RunError
from ..settings.config import ConfigError
from ..train import resolve


def median_ms(work, repeats: int = 20) -> float:
    """Median milliseconds of ``work()`` on the current CUDA stream, after three warm-up calls."""
    for _ in range(3):
        work()
    times = []
    for _ in range(repeats):
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        start.record()
        work()
        end.record()
        end.synchronize()
        times.append(start.elapsed_time(end))
    return statistics.median(times)


def time_actor(actor: ImageModel, obs: TensorDict, mini_batch: TensorDict) -> tuple[float, float]:
    """Milliseconds of ``actor``'s forward pass on ``obs`` and of a gradient step on ``mini_batch``."""
    optimizer = torch.optim.Adam(actor.parameters(), lr=1e-4, fused=True)
    actions = torch.zeros(mini_batch.batch_size[0], 1, device=mini_batch.device)

    def forward():
        with torch.inference_mode():
            actor(obs, stochastic_output=True)

    def step():
        actor(mini_batch, stochastic_output=True)
        loss = actor.get_output_log_prob(actions).mean() + actor.output_entropy.mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    return median_ms(forward), median_ms(step)


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, RunError, StageError):
        cfg, _, _ = resolve(sys.argv[1:] if argv is None else argv)
    device, n, camera = cfg.env.device, cfg.env.num_envs, cfg.env.camera
    if not device.startswith("cuda") or not camera.enabled:
        print("error: encoder timing needs a task seen by a camera (e.g. --task cartpole-balance-rgb) and --device "
              "cuda:N", file=sys.stderr)
        return 2
    batch = n * cfg.agent.num_steps_per_env // cfg.agent.algorithm.num_mini_batches
    channels = camera.channels * camera.frame_stack
    dtype = torch.uint8 if camera.image == "rgb" else torch.float32
    rows = max(n, batch)
    shape = (rows, channels, camera.height_px, camera.width_px)
    frames = (torch.randint(0, 256, shape, dtype=torch.uint8, device=device) if dtype == torch.uint8
              else torch.rand(shape, device=device) * 8.0)
    everything = TensorDict({"policy": frames, "critic": torch.zeros(rows, 4, device=device)},
                            batch_size=[rows], device=device)
    obs = everything[:n]
    actor_cfg = to_rsl_rl(cfg.agent, images=True)["actor"]
    actor_cfg = {key: value for key, value in actor_cfg.items() if key not in ("class_name", "precision")}
    groups = {"actor": ["policy"], "critic": ["critic"]}
    name = torch.cuda.get_device_name(device)
    print(f"{name}: encoder {cfg.agent.actor.cnn}, frames {tuple(shape[1:])} {camera.image}, rollout forward of {n}, "
          f"gradient step on {batch}")
    print("| precision | channels-last | cuDNN benchmark | rollout forward ms | gradient step ms |")
    print("|---|---|---|---|---|")
    for precision, channels_last, benchmark in itertools.product(("bfloat16", "float32"), (True, False),
                                                                 (False, True)):
        torch.backends.cudnn.benchmark = benchmark
        torch.manual_seed(0)
        actor = ImageModel(obs, groups, "actor", 1, precision=precision, **actor_cfg)
        actor.channels_last = channels_last
        forward_ms, step_ms = time_actor(actor.to(device), obs, everything[:batch])
        print(f"| {precision} | {channels_last} | {benchmark} | {forward_ms:.3f} | {step_ms:.3f} |", flush=True)
    torch.backends.cudnn.benchmark = False
    return 0


if __name__ == "__main__":
    sys.exit(main())
