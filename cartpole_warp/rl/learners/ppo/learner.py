"""``PpoLearner``: rsl-rl's PPO (``agent.algorithm.class_name``: this package's ``SyncFreePPO`` or rsl-rl's ``PPO``) as
the runner's learner: each iteration a rollout of ``num_steps_per_env`` steps into rsl-rl's storage, the returns, then
PPO's update. On a GPU with ``cuda_graph`` the rollout runs op by op once (which makes rsl-rl's lazily allocated
storage), is captured with the env's Warp kernels the second time and replayed after."""

from __future__ import annotations

from ....wrappers import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import contextlib
import io
from collections.abc import Callable

import torch
from rsl_rl.utils import resolve_callable
from tensordict import TensorDict

from ....engine.streams import PhaseClock, TorchGraph
from ....evaluation.rollouts import Policy
from ....evaluation.statistics import EpisodeStats
from ....settings.config import EnvConfig
from ....wrappers.rsl_rl import RslRlVecEnv
from ....wrappers.tensordict_import import mark_for_compile
from ...config import TrainConfig
from ...distributed import Ranks
from ...policies import deterministic
from .. import Readout
from .sync_free import SyncFreePPO


class PpoLearner:
    """rsl-rl's PPO on ``env`` (``rl.learners.Learner``, of one member); ``alg`` is rsl-rl's algorithm object."""

    num_members = 1

    @staticmethod
    def env_config(cfg: TrainConfig, env_cfg: EnvConfig, ranks: Ranks) -> EnvConfig:
        return env_cfg

    def __init__(self, env: RslRlVecEnv, cfg: TrainConfig, rsl_rl_cfg: dict, episodes: EpisodeStats):
        if cfg.agent.torch_compile_mode is not None:
            mark_for_compile()
        self.env, self.episodes, self.device = env, episodes, env.device
        self.clock = PhaseClock(self.device, phases=2)
        self.num_steps_per_env = rsl_rl_cfg["num_steps_per_env"]
        alg_class = resolve_callable(rsl_rl_cfg["algorithm"]["class_name"])
        with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints its resolved observation sets and models
            self.alg = alg_class.construct_algorithm(env.get_observations(), env, rsl_rl_cfg, self.device)
        self.distributed = rsl_rl_cfg.get("multi_gpu") is not None
        graphable = (cfg.agent.cuda_graph and isinstance(self.alg, SyncFreePPO) and cfg.console != "rsl_rl"
                     and torch.device(self.device).type == "cuda")
        self._rollout_graph = TorchGraph(self.device) if graphable else None
        self.on_step: Callable[[torch.Tensor, torch.Tensor, dict], None] | None = None
        """Called with each step's rewards, dones and extras (rsl-rl's console: its logger's ``process_env_step``);
        a rollout with it is never captured."""

    @property
    def actor(self) -> torch.nn.Module:
        return self.alg.get_policy()

    def read(self, losses: dict) -> Readout:
        return Readout.of_one(self.episodes.pop(all_processes=self.distributed), self.alg.learning_rate,
                              self.actor.output_std, losses)

    @property
    def episode_steps(self) -> torch.Tensor:
        return self.env.episode_length_buf[None]

    def retire(self, member: int):
        """Nothing: the run ends with its one member."""

    def member_actor(self, member: int = 0) -> torch.nn.Module:
        self.alg.eval_mode()
        return self.actor

    def evaluation_policy(self) -> Policy:
        return deterministic(self.actor)

    def train_mode(self):
        self.alg.train_mode()

    def eval_mode(self):
        self.alg.eval_mode()

    def begin(self, first_iteration: int, end_iteration: int):
        """Train mode; under torchrun rank 0's parameters to every process."""
        self.alg.train_mode()
        if self.distributed:
            self.alg.broadcast_parameters()

    def iteration(self, obs: TensorDict, it: int) -> tuple[TensorDict, dict]:
        self.clock.mark(0)
        with torch.inference_mode():
            obs = self.collect(obs)
        self.clock.mark(1)
        losses = self.alg.update()
        self.clock.mark(2)
        return obs, losses

    def _rollout(self, obs: TensorDict) -> TensorDict:
        """One iteration's experience: ``num_steps_per_env`` x (act, env step, storage, episode statistics), then the
        returns; the last observations out. Only device work unless ``on_step`` is set."""
        for _ in range(self.num_steps_per_env):
            actions = self.alg.act(obs)
            obs, rewards, dones, extras = self.env.step(actions.to(self.env.device))
            obs, rewards, dones = obs.to(self.device), rewards.to(self.device), dones.to(self.device)
            self.alg.process_env_step(obs, rewards, dones, extras)
            self.episodes.add(dones.bool(), extras["episode_return"], extras["episode_length"], extras["time_outs"])
            if self.on_step is not None:
                self.on_step(rewards, dones, extras)
        self.alg.compute_returns(obs)
        return obs

    def collect(self, obs: TensorDict) -> TensorDict:
        """An iteration's experience (``_rollout``), captured and replayed where the rollout is graphed (also what
        ``tools.timing`` times)."""
        if self._rollout_graph is None:
            return self._rollout(obs)
        return self._rollout_graph.with_inputs(obs, self._rollout)

    def state_dict(self, member: int = 0) -> dict:
        """rsl-rl's networks and optimizer."""
        return self.alg.save()

    def load_state_dict(self, loaded: dict, load_cfg: dict | None, strict: bool, member: int = 0):
        self.alg.load(loaded, load_cfg, strict)

    def release_graphs(self):
        if self._rollout_graph is not None:
            self._rollout_graph.release()
        if isinstance(self.alg, SyncFreePPO):
            self.alg.release_graph()
