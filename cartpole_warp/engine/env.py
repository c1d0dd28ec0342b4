"""``BatchedEnv``: the machinery of a batched env on Newton and Warp, robot-agnostic. A task subclasses it with its
sizes, its stage and joint roles, and four Warp functions (``TaskFunctions``); everything else lives here.

One env step: clip actions to [-1, 1] -> joint forces of the task (of the action d steps ago, times the actuator scale,
with domain randomization) -> ``decimation`` solver steps (each after the joints' friction) -> observe, reward and end
reason of the task -> time limit, returns and lengths, keep the final observation -> masked reset of the ended envs
from the task's reset sampler -> new physics for them (``randomization``). All of it is Warp work on persistent arrays,
captured once as a graph per CPU shard (or on CUDA) and replayed. The kernels (``kernels.py``) are built from the
task's functions once per task and compiled into one Warp module per task; this module holds their buffers, launches
and the torch side (input checks, views, info).
"""

import abc
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import warp as wp

from ..settings.config import EnvConfig, TaskConfig, check_seed
from ..settings.files import data_path
from . import randomization
from .buffers import EnvBuffers
from .kernels import COMMON_ENDS, TaskFunctions, build_kernels, constants_of, init_rng, step_settings
from .observations import observations_of
from .randomization import PhysicalParams
from .runtime import Shard, ShardedStep, load_modules, resolve_device, shard_bounds, timed, warp_output
from .scene import JointRole, Scene, build_scene, preloadable_modules, set_gradients, shardable
from .spaces import VectorSpaces

if TYPE_CHECKING:
    import torch  # imported where used: parsing a command line needs no torch


class TaskDeclaration(abc.ABC):
    """What a task's subclass of ``BatchedEnv`` declares: the class attributes below and ``joints``; its spec
    (observation, action, reward, ends, reset) lives in its docstring."""

    config_class: ClassVar[type[TaskConfig]]
    """The task's settings (``env.task``); its float fields are the constants its functions read (``p``)."""
    num_obs: ClassVar[int]
    num_actions: ClassVar[int]
    stage: ClassVar[str | Path]
    """The task's stage: a file name in the package's usd/ folder, or the Path of a stage elsewhere (e.g. in an
    installed package); ``sim.stage_path`` names another."""
    joint_roles: ClassVar[tuple[str, ...]]
    """The roles of the joints the task drives or reads, in the order of its ``Joints`` vectors."""
    task_ends: ClassVar[tuple[str, ...]] = ()
    """Names of the task's failure codes FIRST_TASK_END, FIRST_TASK_END + 1, ..."""
    obs_mirror: ClassVar[tuple[float, ...] | None] = None
    """The task's left-right symmetry, where it has one: the signs that turn an observation into that of the mirrored
    state (every joint position and velocity negated); training appends mirrored samples to PPO's mini-batches
    (``agent.algorithm.symmetry``). None: no symmetry."""
    action_mirror: ClassVar[tuple[float, ...] | None] = None
    """The signs that mirror an action, with ``obs_mirror``."""
    functions: ClassVar[TaskFunctions]

    @abc.abstractmethod
    def joints(self, task: TaskConfig) -> list[JointRole]:
        """The stage's joint for each role of ``joint_roles`` (name and type), from the task's settings."""


class BatchedEnv(VectorSpaces, TaskDeclaration):
    """``num_envs`` copies of a task's robot stepped together on persistent Warp buffers (the machinery of every task:
    a task subclasses it with its ``TaskDeclaration``). Envs that end are reset within the same ``step``: the returned
    observation is the new episode's first one, and ``info["final_obs"]`` holds the observation at which the episode
    ended. ``step`` returns fresh tensors, ``step_views`` the zero-copy views (``obs_buf`` and friends) that the next
    step overwrites. ``info`` keys (tensors on ``device``): ``final_obs`` (N, num_obs); ``episode_return`` (N,),
    ``episode_length`` (N,) and ``end_reason`` (N,) int32 (codes named by ``end_reasons``), valid where terminated |
    truncated; ``nonfinite_actions``, ``nonfinite_states`` and ``diverged_states`` (scalars, totals since
    construction): non-finite actions are applied as 0, and a non-finite physics state, or one beyond
    ``sim.divergence_limit``, ends its episode (reward 0) with the last sound observation.

    On the CPU the envs are split into ``shards`` (one Newton scene each) stepped in parallel threads
    (``sim.cpu_threads``); results do not depend on the split. ``scene`` is the scene holding env 0. Each env
    simulates its own physical parameters (``physical_params()``): the stage's, or drawn by the config's
    ``randomization`` at each episode start (or once), or set by ``set_physical_params``.
    """

    def __init__(self, cfg: EnvConfig):
        self.cfg = cfg.validate()
        with warp_output(cfg.verbose):
            self._build(cfg)

    def _build(self, cfg: EnvConfig):
        """Scene, buffers, first reset and the step's graphs: every Warp module the env steps with is loaded here."""
        self.build_time_s: dict[str, float] = {}
        """Seconds the construction took: 'newton' (Warp's start-up and Newton's import, in a process's first env),
        'kernels' (loading or compiling the Warp modules, first launches), 'scene' (stage import, replication,
        solver), 'capture' (the step's graphs)."""
        with timed(self.build_time_s, "newton"):
            self.device = resolve_device(cfg.device)
            joints = self.joints(cfg.task)
        self.num_envs = cfg.num_envs
        self.max_episode_length = cfg.max_episode_length
        self.env_dt = cfg.sim.env_dt
        self.end_reasons = COMMON_ENDS + self.task_ends
        """Names of the ``end_reason`` codes, by code."""
        self._kernels = build_kernels(self.functions, self.config_class, len(self.joint_roles), self.num_actions,
                                      self.num_obs, f"{type(self).__module__}.{type(self).__qualname__}.kernels")
        stage = self.stage_path = (cfg.sim.stage_file if cfg.sim.stage_path
                                   else self.stage if isinstance(self.stage, Path) else data_path("usd", self.stage))
        cfg.randomization.validate(self.joint_roles)
        self.observations = observations_of(cfg.camera, cfg.num_envs, self.device)
        """What the policy observes: the task's state or camera frames (``engine.observations``)."""
        bounds = shard_bounds(cfg.num_envs, self.device, cfg.sim.cpu_threads, shardable(cfg.sim, self.device))
        with timed(self.build_time_s, "kernels"):
            set_gradients(cfg.sim.solver, cfg.sim.gradients)
            load_modules(self.warp_modules(), self.device, type(self).__name__)
        with timed(self.build_time_s, "scene"):
            self.shards = [Shard(i, start, stop, build_scene(stop - start, self.device, cfg.sim, stage, joints))
                           for i, (start, stop) in enumerate(bounds)]
        self.task_constants = constants_of(self.config_class, cfg.task)
        self._role_dofs = wp.array(self.scene.role_dofs, dtype=int, device=self.device)
        from .streams import StreamOrder  # torch, imported once an env is built

        self._order = StreamOrder(self.device)
        self.physics = PhysicalParams(cfg.randomization, self.joint_roles, [joint.kind for joint in joints], self.scene,
                               self.num_envs, self.device)
        """The per-env physical parameters and their draws."""
        self.observations.attach(self.shards)
        self._allocate()
        with timed(self.build_time_s, "kernels"):
            self._seed(cfg.seed)
            self._reset_where(self.buffers.all_envs, None)
            wp.synchronize_device(self.device)
        with timed(self.build_time_s, "capture"):
            self._step = ShardedStep(self.shards, self.shard_step, self._order, capture=cfg.sim.capture != "off")

    def warp_modules(self) -> list[wp.Module]:
        """The Warp modules this env launches kernels of (loaded when it is built): Newton's (but mujoco-warp's and its
        camera's), the machinery's, the randomization's, the task's and the frame stacks'."""
        return [*preloadable_modules(self.cfg.sim.solver), init_rng.module, wp.get_module(randomization.__name__),
                self._kernels.end_step.module, *self.observations.modules]

    @property
    def sees_images(self) -> bool:
        """Whether the policy observes camera frames (then ``get_state_observations`` is the critic's state)."""
        return self.observations.images

    @property
    def cameras(self) -> "list | tuple":
        """Each shard's camera views (none where the policy observes the task's state)."""
        return self.observations.cameras

    @property
    def scene(self) -> Scene:
        """The Newton scene holding env 0 (all envs unless the CPU shards them)."""
        return self.shards[0].scene

    def _allocate(self):
        """The batch's buffers (``EnvBuffers``), the step's settings, each shard's structs and the torch views."""
        k = self._kernels
        self.buffers = EnvBuffers(k, self.num_envs, len(self.joint_roles), self.cfg.randomization.action_delay_steps,
                                  len(self.shards), self.observations, self.device)
        self._settings = step_settings(k, self.cfg)
        self._shard_structs = [self.buffers.structs_of(shard, self._role_dofs) for shard in self.shards]
        views = self.buffers.torch
        self.actions_buf, self.obs_buf = views.actions, views.obs
        self.state_obs_buf = views.state_obs
        """(N, num_obs) the task's state observations (zero-copy): the policy's observations unless it sees images,
        else the privileged observations of an asymmetric critic."""
        self.final_state_buf = views.final_state
        """(N, 2 x joint roles) where the last step ended an episode, the joint state it ended at (``set_state``'s
        layout; the last sound one if the state turned non-finite or diverged), zero-copy: the robot is already
        reset there."""
        self.reward_buf, self.terminated_buf, self.truncated_buf = views.reward, views.terminated, views.truncated

    @property
    def episode_length_buf(self) -> "torch.Tensor":
        """(N,) int32 time-out counter: the episode is truncated when it reaches ``max_episode_length`` (zero-copy;
        assigning copies into it, as rsl-rl's ``init_at_random_ep_len`` does to spread the time-outs). The
        ``episode_length`` reported at the end is the steps the episode really ran, whatever was assigned."""
        return self.buffers.torch.time_out_count

    @episode_length_buf.setter
    def episode_length_buf(self, value: "torch.Tensor"):
        self.buffers.torch.time_out_count.copy_(value)

    def _apply_actions(self, shard: Shard):
        (robot, episodes, _), rows, b = self._shard_structs[shard.index], shard.rows, self.buffers
        wp.launch(self._kernels.apply_actions, dim=shard.num_envs, device=self.device,
                  inputs=[self.task_constants, robot, episodes, rows(self.physics.delay),
                          rows(self.physics.actuator_scale)],
                  outputs=[rows(b.actions), rows(b.action_history), rows(b.actuator_f),
                           shard.slot(b.nonfinite_actions)])

    def _simulate(self, shard: Shard):
        """``decimation`` solver steps, each after the joints' friction where it is randomized."""
        friction = self.physics.friction_hook(shard, self.buffers.actuator_f, self._role_dofs)
        shard.scene.simulate(self.cfg.sim.physics_dt, self.cfg.sim.decimation, friction)

    def physics_step(self, shard: Shard):
        """Random actions, the task's joint forces and the solver steps of one shard's env step (``tools.bench``)."""
        b = self.buffers
        wp.launch(self._kernels.random_actions, dim=shard.num_envs, inputs=[shard.rows(b.episodes.rng_state)],
                  outputs=[shard.rows(b.actions)], device=self.device)
        self._apply_actions(shard)
        self._simulate(shard)

    def shard_step(self, shard: Shard):
        """One env step's Warp work for ``shard``: what its captured graph replays (``tools.nodes`` counts it)."""
        robot, episodes, results = self._shard_structs[shard.index]
        b = self.buffers
        self._apply_actions(shard)
        self._simulate(shard)
        self.observations.after_physics(shard)
        wp.launch(self._kernels.end_step, dim=shard.num_envs,
                  inputs=[self.task_constants, self._settings, robot, shard.rows(b.actions)],
                  outputs=[episodes, results, shard.slot(b.nonfinite_states), shard.slot(b.diverged_states)],
                  device=self.device)
        self.observations.after_step(shard, results)
        if self.physics.drawn and self.cfg.randomization.at == "reset":
            self.physics.draw(shard, b.episodes.rng_state, b.results.end_reason)

    def _seed(self, seed: int, start: int = 0, stop: int | None = None):
        """Seed envs [start, stop) (all by default) as envs 0, 1, ... of an env seeded with ``seed``."""
        stop = self.num_envs if stop is None else stop
        for shard in self.shards:
            lo, hi = max(start, shard.start), min(stop, shard.stop)
            if lo < hi:
                wp.launch(init_rng, dim=hi - lo, inputs=[int(seed), lo - start],
                          outputs=[self.buffers.episodes.rng_state[lo:hi]], device=self.device)

    def _reset_where(self, mask: wp.array, ended: wp.array | None):
        """A new episode where ``mask`` (bool; ``buffers.all_envs``: every env) is set, and new physics where it is
        randomized and ``ended`` (int32 flags; None: everywhere) is set."""
        for shard in self.shards:
            robot, episodes, _ = self._shard_structs[shard.index]
            wp.launch(self._kernels.reset_masked, dim=shard.num_envs,
                      inputs=[shard.rows(mask), self.task_constants, self._settings],
                      outputs=[robot, episodes], device=self.device)
            self.observations.start(shard, mask)
            if self.physics.drawn:
                self.physics.draw(shard, self.buffers.episodes.rng_state, ended)

    def _check(self, name: str, value, shapes: tuple, dtype: "torch.dtype") -> "torch.Tensor":
        from .streams import check_tensor

        return check_tensor(name, value, shapes, dtype, self.device)

    def _outputs(self):
        views = self.buffers.torch
        return {k: v.clone() for k, v in views.info.items()} | {k: v.sum() for k, v in views.counters.items()}

    def reset(self, seed: int | None = None) -> "tuple[torch.Tensor, dict]":
        """Start a new episode in every env (re-seeding the RNG when ``seed`` is given): (obs, info)."""
        if seed is not None:
            check_seed(seed)
        with self._order:
            if seed is not None:
                self._seed(seed)
            self._reset_where(self.buffers.all_envs, None)
        return self.obs_buf.clone(), self._outputs()

    def restart(self, start: int, stop: int, seed: int) -> "torch.Tensor":
        """Envs [start, stop) begin new episodes as envs 0, 1, ... of an env of ``stop - start`` envs reset with
        ``seed`` do (their random streams re-seeded: the same start states, physics draws and observation noise;
        bitwise with Featherstone, whose state is the joints'); the others go on undisturbed. Returns the observations
        (all envs)."""
        check_seed(seed)
        if not 0 <= start < stop <= self.num_envs:
            raise ValueError(f"restart: envs [{start}, {stop}) must be a block of the {self.num_envs} envs")
        views = self.buffers.torch
        views.mask_in.zero_()
        views.mask_in[start:stop] = True
        views.restart_in.copy_(views.mask_in)
        with self._order:
            self._seed(seed, start, stop)
            self._reset_where(self.buffers.mask_in, self.buffers.restart_in)
        return self.obs_buf.clone()

    def step(self, actions: "torch.Tensor"):
        """Apply actions for one env step: (obs, reward, terminated, truncated, info), autoresetting ended envs."""
        return (*(view.clone() for view in self.step_views(actions)[:4]), self._outputs())

    def step_views(self, actions: "torch.Tensor"):
        """``step`` as the zero-copy views that the next step overwrites (for a loop that uses each step's results at
        once), ``info`` without the counters' totals (``nonfinite_actions`` and the like)."""
        import torch

        n, a = self.num_envs, self.num_actions
        actions = self._check("actions", actions, ((n, a), (n,)) if a == 1 else ((n, a),), torch.float32)
        self.actions_buf.copy_(actions.reshape(n, a))
        self._step()
        return self.obs_buf, self.reward_buf, self.terminated_buf, self.truncated_buf, dict(self.buffers.torch.info)

    def set_state(self, states: "torch.Tensor", mask: "torch.Tensor | None" = None) -> "torch.Tensor":
        """Start new episodes from ``states`` (N, 2 x joint roles): for each role in ``joint_roles`` order, its
        position (m or rad) then its velocity (m/s or rad/s); where ``mask`` (N,) bool is set (everywhere by default).
        Returns the observations."""
        import torch

        n = self.num_envs
        states = self._check("states", states, ((n, 2 * len(self.joint_roles)),), torch.float32)
        if not torch.isfinite(states).all():
            raise ValueError("states: every value must be finite")
        mask = self._check("mask", mask, ((n,),), torch.bool) if mask is not None else None
        self.buffers.torch.states_in.copy_(states)
        self.buffers.torch.mask_in[:] = True if mask is None else mask
        with self._order:
            for shard in self.shards:
                robot, episodes, _ = self._shard_structs[shard.index]
                wp.launch(self._kernels.set_states_masked, dim=shard.num_envs,
                          inputs=[shard.rows(self.buffers.states_in), shard.rows(self.buffers.mask_in),
                                  self.task_constants, self._settings],
                          outputs=[robot, episodes], device=self.device)
                self.observations.start(shard, self.buffers.mask_in)
        return self.obs_buf.clone()

    def physical_params(self) -> "dict[str, torch.Tensor]":
        """What each env simulates, in SI units: (N,) tensors named as in ``physics.table`` (``engine.parameters``:
        per joint role ``<role>_mass_kg``, ``_com_m``, ``_inertia_kg_m2``, ``_damping_*``, ``_friction_*``; per
        env ``actuator_scale``, ``gravity_m_s2``, ``action_delay_steps``), then the task's own
        (``task_physical_params``)."""
        values = self.physics.values()
        return values | self.task_physical_params(values)

    def task_physical_params(self, values: "dict[str, torch.Tensor]") -> "dict[str, torch.Tensor]":
        """The task's own physical parameters, derived from the machinery's ``values`` (none by default)."""
        return {}

    def set_physical_params(self, **values: "torch.Tensor"):
        """Set what the named envs simulate from now on: (N,) tensors on ``device`` in SI units, named as in
        ``physical_params`` (derived values excepted); the others keep theirs. With randomization ``at='reset'``, an
        env's next episode start draws anew. A first friction on an env that does not randomize it captures the step
        again (a graph captured around ``step`` before then lacks it)."""
        import torch

        for name, value in values.items():
            self._check(name, value, ((self.num_envs,),), value.dtype if torch.is_tensor(value) else torch.float32)
        if self.physics.set(values):  # friction from now on, which the captured step lacks: capture it again
            self._step.close()
            self._step = ShardedStep(self.shards, self.shard_step, self._order, self._step.replay is not None)
        with self._order, warp_output(self.cfg.verbose):
            for shard in self.shards:
                self.physics.write(shard)

    def close(self):
        """Stop the shard threads (the env cannot step afterwards)."""
        self._step.close()

    def get_observations(self) -> "torch.Tensor":
        """The current observations (``obs_shape``), a fresh tensor."""
        return self.obs_buf.clone()

    def joint_state(self) -> "tuple[torch.Tensor, torch.Tensor]":
        """Each env's joint positions and velocities now, (N, joint roles) each in ``joint_roles`` order (m or rad, m/s
        or rad/s; a hinge's angle relative to the body below it): after a step the state it reached, or the start of
        the episode an autoreset began. Fresh tensors."""
        return wp.to_torch(self.buffers.episodes.last_q).clone(), wp.to_torch(self.buffers.episodes.last_qd).clone()

    def get_state_observations(self) -> "torch.Tensor":
        """The task's state observations (N, num_obs), a fresh tensor (the critic's where the policy sees images)."""
        return self.state_obs_buf.clone()

    def __repr__(self) -> str:
        limit = (f"time limit {self.max_episode_length} steps ({self.cfg.task.episode_length_s:g} s)"
                 if self.cfg.task.has_time_limit else "no time limit")
        return (f"<{type(self).__name__}: {self.num_envs} envs on {self.device}, observations "
                f"{self.single_observation_space}, actions {self.single_action_space}, {limit}, "
                f"env step {self.env_dt:g} s>")
