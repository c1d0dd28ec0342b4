"""Policies outside the training loop: rsl-rl's ``train_cfg`` dict of the agent's settings (``to_rsl_rl``), checkpoints
read with clear errors, the actor of a checkpoint and its deterministic policy (``load_actor``, ``load_policy``: no
``OnPolicyRunner``, no optimizer), and the exports of an actor (``export_policy``: ONNX, a ``torch.export`` program and
TorchScript)."""

from __future__ import annotations

from ..wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import contextlib
import dataclasses
import io
import logging
import re
import warnings
from pathlib import Path

import torch
from rsl_rl.modules.distribution import GaussianDistribution
from rsl_rl.utils import resolve_class, resolve_obs_groups
from rsl_rl.utils.log_writer import LogWriter
from tensordict import TensorDict

from ..evaluation.rollouts import Policy
from ..settings.agent import RunnerConfig
from ..settings.files import atomic_write
from ..wrappers.rsl_rl import RslRlVecEnv
from ..wrappers.rsl_rl import mirror as mirror_batch
from .image_model import ImageModel
from .runs import RunError

ONNX_FILE, PROGRAM_FILE, JIT_FILE = "policy.onnx", "policy.pt2", "policy.pt"
"""The exports' file names (in a run's ``exported/``): ONNX, the ``torch.export`` program, TorchScript."""

TORCH_DEPRECATION = (DeprecationWarning, FutureWarning)
"""The categories of torch's TorchScript deprecations: DeprecationWarning up to 2.14, FutureWarning in 2.15."""
EXPORT_WARNINGS = (
    (TORCH_DEPRECATION, "`torch.jit.script` is deprecated",
     "policy.pt is TorchScript on purpose: rsl-rl's and Isaac Lab's users load it (policy.pt2 is its successor)"),
    (TORCH_DEPRECATION, "`torch.jit.save` is deprecated", "the same file's writing"),
    ((FutureWarning,), "`isinstance(treespec, LeafSpec)` is deprecated", "torch.export's own pytree code raises it"),
)
"""The warnings that an export silences, each by its categories and the start of its message, and why; any other
warning reaches the user."""
ONNX_REGISTRATION_LOGGER = "torch.onnx._internal.exporter._registration"
"""The logger of the ONNX exporter's operator table, which warns once per torchvision operator it skips where
torchvision is not installed (a policy uses none): set to ERROR while exporting."""

RSL_RL_KEYS = ("num_steps_per_env", "save_interval", "run_name", "logger", "torch_compile_mode", "algorithm", "actor",
               "critic")
"""The fields of ``RunnerConfig`` that rsl-rl's ``train_cfg`` holds; the others are the project's (the run's length and
names, the learners and their sections)."""

SYNC_FREE_PPO = "cartpole_warp.rl.learners.ppo.sync_free:SyncFreePPO"
"""rsl-rl's ``class_name`` of the PPO learner's ``SyncFreePPO`` (``agent.algorithm.class_name: SyncFreePPO``), named
by path: the networks' layer does not import the learners'."""


def gaussian_sample(mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """Gaussian actions as mean + std * N(0, 1), drawn without reading anything back from the device."""
    return mean + std * torch.randn_like(mean)


class SyncFreeGaussian(GaussianDistribution):
    """rsl-rl's ``GaussianDistribution`` sampled as mean + std * N(0, 1). ``torch.normal(mean, std)``, which rsl-rl's
    ``sample`` calls, first reads ``std.min() >= 0`` back to the host: a device sync at every policy step, and an error
    inside a CUDA-graph capture. Same distribution (std is clamped positive), other random numbers."""

    def sample(self) -> torch.Tensor:
        with torch.no_grad():
            return gaussian_sample(self.mean, self.std)


class SquashedGaussian(SyncFreeGaussian):
    """``SyncFreeGaussian`` whose deterministic output is tanh(mean): a deterministic policy's actions in [-1, 1] (the
    off-policy learner's actor, ``agent.learner: fasttd3``), in training, in play and in the exports."""

    def deterministic_output(self, mlp_output: torch.Tensor) -> torch.Tensor:
        return torch.tanh(mlp_output)

    def as_deterministic_output_module(self) -> torch.nn.Module:
        return torch.nn.Tanh()


class NullLogWriter(LogWriter):
    """Metrics writer for ``agent.logger: none``: checkpoints and summary are still written, metrics are not."""

    def __init__(self, log_dir: str):
        self.log_dir = log_dir

    def add_scalar(self, tag: str, scalar_value: float, global_step: int) -> None:
        """Drop the metric."""


def update_normalization(models, obs: TensorDict | torch.Tensor):
    """rsl-rl's observation-normalizer update of each of ``models`` (an ``MLPModel``'s ``update_normalization`` of a
    TensorDict, a bare ``EmpiricalNormalization``'s ``update`` of a tensor), its statistics kept in the tensors they
    started in: rsl-rl's update binds a new tensor to ``_std``, which captured rollouts and updates would never read
    (they would normalise with the std of the capture forever)."""
    for model in models:
        normalizer = getattr(model, "obs_normalizer", model)
        std = getattr(normalizer, "_std", None)
        if normalizer is model:
            model.update(obs)
        else:
            model.update_normalization(obs)
        if isinstance(std, torch.Tensor) and normalizer._std is not std:
            std.copy_(normalizer._std)
            normalizer._std = std


def read_checkpoint(path: str | Path, device: str) -> dict:
    """A checkpoint's dict on ``device``; RunError naming the file if it is unreadable or not rsl-rl's."""
    try:
        loaded = torch.load(path, weights_only=False, map_location=device)
    except Exception as err:  # torch.load raises many types for truncated or foreign files
        raise RunError(f"cannot read checkpoint {path}: {type(err).__name__}: {err}") from None
    if not isinstance(loaded, dict) or "actor_state_dict" not in loaded or "iter" not in loaded:
        raise RunError(f"{path} is not an rsl-rl checkpoint (no actor_state_dict / iter)")
    return loaded


@contextlib.contextmanager
def networks_must_fit(path: str | Path):
    """RunError naming ``path`` when its networks do not load into the configured ones."""
    try:
        yield
    except (RuntimeError, KeyError, ValueError) as err:
        raise RunError(f"checkpoint {path} does not match the configured networks "
                       f"(e.g. agent.actor.hidden_dims): {str(err).splitlines()[0]}") from None


def build_networks(env: RslRlVecEnv, cfg: dict, critic: bool = True) -> tuple[torch.nn.Module, torch.nn.Module | None]:
    """The actor and (where ``critic``) the critic of rsl-rl's ``train_cfg`` dict ``cfg`` on ``env``'s device, built
    as rsl-rl's PPO builds them (its own ``resolve_class`` and ``resolve_obs_groups``, the actor first) but without
    its storage and optimizer."""
    obs = env.get_observations()
    with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the resolved observation sets
        groups = resolve_obs_groups(obs, cfg["obs_groups"], ["actor", "critic"])
    actor_class, actor_cfg = resolve_class(cfg["actor"])
    actor = actor_class(obs, groups, "actor", env.num_actions, **actor_cfg).to(env.device)
    if not critic:
        return actor, None
    critic_class, critic_cfg = resolve_class(cfg["critic"])
    return actor, critic_class(obs, groups, "critic", 1, **critic_cfg).to(env.device)


def load_actor(env: RslRlVecEnv, agent: RunnerConfig, checkpoint: str | Path) -> torch.nn.Module:
    """``checkpoint``'s actor in eval mode (``build_networks``, without the critic): playing and exporting need no
    runner or optimizer, and a torch optimizer imports ``torch._dynamo`` when it is made."""
    actor, _ = build_networks(env, to_rsl_rl(agent, images=env.images), critic=False)
    with networks_must_fit(checkpoint):
        actor.load_state_dict(read_checkpoint(checkpoint, env.device)["actor_state_dict"])
    return actor.eval()


def load_policy(env: RslRlVecEnv, agent: RunnerConfig, checkpoint: str | Path) -> Policy:
    """The deterministic policy of ``checkpoint``'s actor (``load_actor``)."""
    return deterministic(load_actor(env, agent, checkpoint))


def deterministic(actor: torch.nn.Module) -> Policy:
    """``actor`` (rsl-rl's ``MLPModel`` in eval mode: the Gaussian's mean) as a policy of observation tensors."""

    def act(obs: torch.Tensor) -> torch.Tensor:
        return actor(TensorDict({"policy": obs}, batch_size=[obs.shape[0]]))

    return act


def to_rsl_rl(agent: RunnerConfig, mirror: bool = False, images: bool = False) -> dict:
    """rsl-rl's ``train_cfg`` dict of ``agent``: class names added (this package's as ``module:name`` of the classes
    themselves), our own fields left out; ``mirror``: the task has a mirror (``symmetry`` applies); ``images``: the
    policy observes camera frames (a CNN actor, ``ImageModel``, on the 'policy' group; the critic an MLP on the
    task's state, the 'critic' group: an asymmetric actor-critic)."""
    cfg = {key: value for key, value in dataclasses.asdict(agent).items() if key in RSL_RL_KEYS}
    cnn = cfg["actor"].pop("cnn")
    del cfg["algorithm"]["symmetry"]
    if agent.algorithm.symmetry and mirror:
        cfg["algorithm"]["symmetry_cfg"] = {"use_data_augmentation": True,
                                            "data_augmentation_func": _path(mirror_batch)}
    cfg["actor"]["class_name"] = "MLPModel"
    cfg["actor"]["distribution_cfg"]["class_name"] = "GaussianDistribution"
    if agent.algorithm.class_name == "SyncFreePPO":
        cfg["algorithm"]["class_name"] = SYNC_FREE_PPO
        cfg["algorithm"]["cuda_graph"] = agent.cuda_graph
        cfg["actor"]["distribution_cfg"]["class_name"] = _path(SyncFreeGaussian)
    if agent.learner == "fasttd3":
        cfg["actor"]["distribution_cfg"]["class_name"] = _path(SquashedGaussian)
    cfg["critic"]["class_name"] = "MLPModel"
    cfg["obs_groups"] = {"actor": ["policy"], "critic": ["policy"]}
    if images:
        cfg["actor"] |= {"class_name": _path(ImageModel), "precision": cnn.pop("precision"), "cnn_cfg": cnn}
        cfg["obs_groups"]["critic"] = ["critic"]
    if agent.logger == "wandb":
        cfg["logger"] = {"class_name": "WandbLogWriter", "project_name": agent.wandb_project}
    elif agent.logger == "none":
        cfg["logger"] = {"class_name": _path(NullLogWriter)}
    return cfg


def export_policy(actor: torch.nn.Module, out_dir: Path) -> list[Path]:
    """Write ``actor``'s deterministic policy into ``out_dir`` for any batch size N (input 'obs' as the env gives it:
    (N, num_obs) float32, or camera frames (N, C, H, W); output 'actions' (N, num_actions)): ``policy.onnx`` (one
    self-contained file, by torch's ``torch.export``-based exporter, its batch dimension named 'batch'), the
    ``torch.export`` program it was made from, ``policy.pt2`` (``torch.export.load(path).module()``; AOTInductor
    compiles it for C++), and TorchScript ``policy.pt`` (``torch.jit.load``, as rsl-rl's exports). rsl-rl's
    ``export_policy_to_onnx`` fixes the batch to 1, hence torch's exporter here. Only ``EXPORT_WARNINGS`` are
    silenced."""
    out_dir = Path(out_dir)
    policy = actor.as_onnx(verbose=False).to("cpu").eval()
    inputs = tuple(torch.cat([dummy, dummy]) for dummy in policy.get_dummy_inputs())  # a batch of 1 would be fixed
    registration = logging.getLogger(ONNX_REGISTRATION_LOGGER)
    level = registration.level
    registration.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            for categories, message, _ in EXPORT_WARNINGS:
                for category in categories:
                    warnings.filterwarnings("ignore", re.escape(message), category)
            batch = torch.export.Dim("batch")
            program = torch.onnx.export(policy, inputs, input_names=policy.input_names,
                                        output_names=policy.output_names, opset_version=18, dynamo=True,
                                        verbose=False, dynamic_shapes=tuple({0: batch} for _ in inputs))
            atomic_write(out_dir / ONNX_FILE, program.save)
            atomic_write(out_dir / PROGRAM_FILE, lambda tmp: torch.export.save(program.exported_program, tmp))
            atomic_write(out_dir / JIT_FILE, lambda tmp: torch.jit.script(actor.as_jit().to("cpu")).save(tmp))
    except Exception as err:
        raise RuntimeError(f"policy export failed: {err}") from err
    finally:
        registration.setLevel(level)
    return [out_dir / ONNX_FILE, out_dir / PROGRAM_FILE, out_dir / JIT_FILE]


def _path(obj) -> str:
    """``module:name``, as rsl-rl's ``resolve_callable`` finds a class or function."""
    return f"{obj.__module__}:{obj.__qualname__}"
