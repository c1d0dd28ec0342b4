"""The CUDA-graph paths of training (rollout and SyncFreePPO update captured once, replayed after) give what the same
work launched op by op gives. They exist on a GPU only: ``CARTPOLE_TEST_DEVICE=cuda:0 pytest tests/test_cuda_graph.py``
runs them there; on the CPU the same code runs op by op and the rest of the suite covers it (and the collector's pause
around a capture is checked here on any device)."""

import pytest
import torch

import cartpole_warp
from cartpole_warp.rl.config import train_config
from cartpole_warp.rl.loop import TrainingLoop
from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv


def runner(device, cuda_graph, task="cartpole-balance", num_envs=4096, evaluated=False):
    """A runner of ``task`` on ``device``; ``evaluated``: with its evaluation envs (else it judges nothing)."""
    cfg = train_config(task)
    cfg.env.num_envs, cfg.env.device, cfg.agent.cuda_graph, cfg.stop_when_solved = num_envs, device, cuda_graph, True
    eval_env = cartpole_warp.make_env(num_envs=cfg.eval.num_envs, device=device, seed=0) if evaluated else None
    torch.manual_seed(0)
    return TrainingLoop(RslRlVecEnv(cartpole_warp.tasks.make(task, num_envs=num_envs, device=device, seed=0)), cfg,
                      None, eval_env)


@pytest.fixture
def cuda(device):
    if not device.startswith("cuda"):
        pytest.skip("CUDA graphs need a GPU: CARTPOLE_TEST_DEVICE=cuda:0")
    return device


def test_graphed_iterations_equal_launched_ones(cuda):
    graphed, launched = runner(cuda, True), runner(cuda, False)
    for r in (graphed, launched):
        torch.manual_seed(1)
        torch.cuda.manual_seed(1)
        r.learn(4)
    assert graphed.learner._rollout_graph.graph is not None, "no graph was used"
    assert graphed.learner.alg._graph.graph is not None, "no graph was used"
    assert launched.learner._rollout_graph is None and launched.learner.alg._graph is None
    graphed.release_graphs()
    assert graphed.learner._rollout_graph.graph is None and graphed.learner.alg._graph.graph is None
    for r in (graphed, launched):
        torch.manual_seed(2)
        torch.cuda.manual_seed(2)
        r.learn(3)
    assert graphed.learner._rollout_graph.graph is not None, "learn captures again after release_graphs"
    for ours, theirs in zip(graphed.learner.alg.actor.parameters(), launched.learner.alg.actor.parameters(),
                            strict=True):
        torch.testing.assert_close(ours, theirs, rtol=1e-4, atol=1e-5)
    for ours, theirs in zip(graphed.records[0].progress.history, launched.records[0].progress.history, strict=True):
        assert ours["episodes"] == theirs["episodes"]
        assert ours["mean_return"] == pytest.approx(theirs["mean_return"], rel=1e-4)


def test_a_graphed_pixel_update_equals_the_launched_one(cuda):
    """The pixel policy's update (encoder in bfloat16 on channels-last tensors) captured as a CUDA graph gives the
    networks that the same update launched op by op gives."""
    graphed, launched = (runner(cuda, graph, "cartpole-balance-rgb", 512) for graph in (True, False))
    for r in (graphed, launched):
        torch.manual_seed(1)
        torch.cuda.manual_seed(1)
        r.learn(4)
    assert graphed.learner.alg._graph.graph is not None and launched.learner.alg._graph is None
    for ours, theirs in zip(graphed.learner.alg.actor.parameters(), launched.learner.alg.actor.parameters(),
                            strict=True):
        torch.testing.assert_close(ours, theirs, rtol=1e-3, atol=1e-4)


def test_graphed_training_solves(cuda):
    trained = runner(cuda, True, evaluated=True)
    trained.learn(150)
    assert trained.records[0].stop_reason == "solved", trained.records[0].progress.history[-1]


def test_a_host_policy_runs_launched_and_a_device_one_captured(cuda):
    """``FirstEpisodesRun`` captures a policy of device work and replays it; a policy that draws on the host (play.py's
    random and multisine agents) runs op by op, so that every step gets its own actions (a graph would replay one)."""
    from cartpole_warp.evaluation.rollouts import FirstEpisodesRun, RandomPolicy, zero_policy

    drawn = []

    class Recorded(RandomPolicy):
        def __call__(self, obs):
            drawn.append(float(super().__call__(obs)[0, 0]))
            return torch.full((obs.shape[0], 1), drawn[-1], device=obs.device)

    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=4, device=cuda, seed=0)
    assert FirstEpisodesRun(env, zero_policy)._graph is not None
    run = FirstEpisodesRun(env, Recorded(1, seed=0))
    assert run._graph is None
    run(5)
    assert len(drawn) == 5 and len(set(drawn)) == 5


def test_the_collector_is_paused_inside_a_capture_and_as_it_was_after():
    """``collection_paused`` (around every capture, which exists on a GPU only): off inside, on again after, also
    after an error, and left off where the caller had paused it."""
    import gc

    from cartpole_warp.engine.runtime import collection_paused

    assert gc.isenabled()
    with collection_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(RuntimeError, match="inside"), collection_paused():
        raise RuntimeError("inside")
    assert gc.isenabled()
    gc.disable()
    try:
        with collection_paused():
            pass
        assert not gc.isenabled(), "a collector the caller paused stays paused"
    finally:
        gc.enable()


DEAD_GRAPH_THEN_CAPTURE = """
import gc, sys, torch, warp
from cartpole_warp.engine.streams import TorchGraph
warp.init()
x, ended_runs = torch.zeros(4, device=sys.argv[1]), []
def ended_run():
    graph = TorchGraph(sys.argv[1])
    graph(lambda: x.add_(1)); graph(lambda: x.add_(1))  # run, then captured
    cycle = [graph]
    cycle.append(cycle)  # only the cyclic collector frees it
    ended_runs.append(cycle)
ended_run()
gc.set_threshold(1, 1, 1)  # every allocation collects every generation
def work():
    ended_runs.clear()  # the ended run's graph is garbage from here, inside the capture
    junk = [[] for _ in range(1000)]  # allocations, which run the collector unless it is paused
    return x.mul_(2)
graph = TorchGraph(sys.argv[1])
graph(lambda: x.mul_(2))
graph(work)
torch.cuda.synchronize()
print("captured", x.tolist())
"""


def test_a_capture_survives_an_ended_runs_graph_left_to_the_collector(cuda, tmp_path):
    """A second training in one process (``tools.sweep``'s seeds) captured while the collector freed the first run's
    graph from a reference cycle: torch's ``CUDAGraph.reset`` inside the capture broke it and the process died
    (SIGSEGV, H200, 2026-12-01). Every capture pauses the collector (``runtime.collection_paused``)."""
    import subprocess
    import sys

    script = tmp_path / "dead_graph.py"
    script.write_text(DEAD_GRAPH_THEN_CAPTURE)
    result = subprocess.run([sys.executable, str(script), cuda], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and "captured [8.0, 8.0, 8.0, 8.0]" in result.stdout, result.stdout + result.stderr
