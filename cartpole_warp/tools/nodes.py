"""The Warp operations of one env step: the nodes of its captured graph, the kernels by name, and on a GPU each
operation's device time.

    python -m cartpole_warp.tools.nodes --task cart-three-pole-swingup --device cuda:0
    python -m cartpole_warp.tools.nodes --task cartpole-swingup --device cpu --tile-gemm off on

Warp counts them itself, two ways: the nodes of a graph captured around one env step of one shard (a CUDA graph's
nodes as Warp's DOT export of it lists them; a CPU graph's operations as Warp records them for its replay), and the
kernels that Warp's launch log names in one uncaptured step. The graph's replay is timed on either device; on CUDA,
Warp's timing API gives every kernel, copy and memset its device time, as means over ``--steps`` uncaptured env steps
(the CPU has no such API). Work outside Warp (torch's, around ``env.step``) is no node of the step: ``tools.timing``
times it.
"""

from __future__ import annotations

import collections
import re
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import warp as wp

from .. import tasks
from ..cli import clean_errors, parse, quiet_libraries
from ..engine.env import BatchedEnv
from ..engine.runtime import collection_paused
from ..engine.scene import StageError
from ..settings.config import ConfigError, Solver, Switch, require


@dataclass
class StepNodes:
    """One env step of one shard, as Warp sees it."""

    nodes: int
    """Operations of the step's captured graph (kernels, copies, memsets and the like)."""
    kernels: collections.Counter[str] = field(default_factory=collections.Counter)
    """Kernel launches by kernel name (Warp's launch log of one uncaptured step)."""
    replay_ms: float = 0.0
    """Wall milliseconds of one replay of the step's graph (the mean of ``steps``, the device synchronised)."""
    device_us: dict[str, tuple[float, float]] = field(default_factory=dict)
    """On CUDA: per operation name (Warp's timing API: 'forward kernel NAME', 'memcpy ...', 'memset ...'), its
    launches and its device time (us) per env step; empty on the CPU."""


class LaunchLog:
    """Warp's logger while Warp logs every launch (``wp.config.print_launches``): keeps the launched kernels' names and
    passes every other message to the logger it replaced."""

    LAUNCH = re.compile(r"^kernel: (\S+) dim:")

    def __init__(self):
        self.kernels: collections.Counter[str] = collections.Counter()

    def __enter__(self) -> LaunchLog:
        self.previous, self.printing = wp.get_logger(), wp.config.print_launches
        wp.set_logger(self)
        wp.config.print_launches = True
        return self

    def __exit__(self, *exc):
        wp.config.print_launches = self.printing
        wp.set_logger(self.previous)

    def info(self, message: str):
        launch = self.LAUNCH.match(message)
        if launch:
            self.kernels[launch.group(1)] += 1
        else:
            self.previous.info(message)

    def debug(self, message: str):
        self.previous.debug(message)

    def warning(self, message: str, category=None, stacklevel: int = 1):
        self.previous.warning(message, category, stacklevel + 1)

    def error(self, message: str):
        self.previous.error(message)


DOT_NODE = re.compile(r'^"(graph_\d+_node_\d+)"\s*\[', re.MULTILINE)
"""A node's line in CUDA's DOT export of a graph (``cudaGraphDebugDotPrint``)."""


def graph_nodes(graph: wp.Graph) -> int:
    """The operations of a graph Warp captured: a CUDA graph's nodes (from Warp's DOT export of it), a CPU graph's
    operations (Warp records them for the replay; Warp 1.19 shows their count on the capture it keeps)."""
    if graph.device.is_cpu:
        return graph._apic_capture.operation_count
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "step.dot"
        wp.capture_debug_dot_print(graph, str(path), verbose=False)
        return len(set(DOT_NODE.findall(path.read_text())))


def step_nodes(env: BatchedEnv, steps: int = 20) -> StepNodes:
    """Count (and on CUDA time) the Warp operations of one env step of ``env``'s first shard; steps the env."""
    shard, device = env.shards[0], env.device
    with LaunchLog() as log:
        env.shard_step(shard)
    with collection_paused(), wp.ScopedCapture(device=device) as capture:
        env.shard_step(shard)
    wp.synchronize_device(device)
    start = time.perf_counter()
    for _ in range(steps):
        wp.capture_launch(capture.graph)
    wp.synchronize_device(device)
    found = StepNodes(graph_nodes(capture.graph), log.kernels, (time.perf_counter() - start) / steps * 1e3)
    if wp.get_device(device).is_cuda:
        wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | wp.TIMING_MEMCPY | wp.TIMING_MEMSET)
        for _ in range(steps):
            env.shard_step(shard)
        totals: dict[str, list[float]] = collections.defaultdict(lambda: [0.0, 0.0])
        for result in wp.timing_end():
            totals[result.name][0] += 1
            totals[result.name][1] += result.elapsed * 1e3
        found.device_us = {name: (count / steps, us / steps) for name, (count, us) in totals.items()}
    return found


def report(found: StepNodes, env: BatchedEnv) -> str:
    """The step's operations as lines of text: the count, the kernels, and on CUDA the costliest first."""
    launches = sum(found.kernels.values())
    lines = [f"{type(env).__name__}, {env.shards[0].num_envs:,} envs ({len(env.shards)} shard(s)) on {env.device}: "
             f"{found.nodes} Warp operations per env step ({launches} kernel launches, "
             f"{found.nodes - launches} copies, memsets and others); its graph replays in {found.replay_ms:.3f} ms"]
    if found.device_us:
        total = sum(us for _, us in found.device_us.values())
        lines.append(f"  device time per env step: {total:,.1f} us (launch by launch, uncaptured)")
        for name, (count, us) in sorted(found.device_us.items(), key=lambda item: -item[1][1]):
            lines.append(f"  {us:9.1f} us  {count:4g} x  {name}")
    else:
        lines += [f"  {count:4d} x  {name}" for name, count in found.kernels.most_common()]
    return "\n".join(lines)


@dataclass
class NodesArgs:
    task: str = tasks.DEFAULT_TASK
    """The registered task to step."""
    device: str = "cpu"
    """'cpu' or 'cuda:N'."""
    num_envs: int = 4096
    """Envs of the env (its first shard's are counted)."""
    solver: Solver = "featherstone"
    """The solver."""
    tile_gemm: list[Switch] = field(default_factory=lambda: ["auto"])
    """SolverFeatherstone's paths to count (``sim.tile_gemm``: 'auto', 'on', 'off')."""
    preset: str | None = None
    """Config preset of the env (None: the task's defaults)."""
    steps: int = 20
    """Env steps averaged over: the graph's replays, and the uncaptured steps that Warp's timing API times (CUDA)."""


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, StageError):
        args = parse(NodesArgs, NodesArgs(), sys.argv[1:] if argv is None else argv, __doc__)
        require(args.steps >= 1, f"--steps must be >= 1, got {args.steps}")
        configs = [tasks.env_config(args.task, args.preset, num_envs=args.num_envs, device=args.device, seed=0,
                                    sim={"solver": args.solver, "tile_gemm": tiles}) for tiles in args.tile_gemm]
        for cfg in configs:
            env = tasks.get(args.task).env_class(cfg)
            try:
                print(f"sim.tile_gemm={cfg.sim.tile_gemm} (tile path: {cfg.sim.tiles(env.device)})")
                print(report(step_nodes(env, args.steps), env), flush=True)
            finally:
                env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
