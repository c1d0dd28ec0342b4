"""tools.nodes: an env step's Warp operations as its captured graph holds them, against the Warp calls that the step
makes (counted here, call by call, in an uncaptured step) and the kernels that Warp's launch log names."""

import collections

import pytest
import warp as wp
from conftest import DEVICE

from cartpole_warp import tasks
from cartpole_warp.tools import nodes

OPERATIONS = [(wp, "launch"), (wp, "launch_tiled"), (wp, "copy"), (wp.array, "zero_"), (wp.array, "fill_"),
              (wp.array, "assign"), (wp.Bvh, "refit")]
"""The Warp calls that put one operation each into a graph (a kernel, a copy, a memset, a BVH refit)."""


def counted_calls(env, monkeypatch) -> collections.Counter:
    """The OPERATIONS calls of one uncaptured env step of ``env``'s first shard, by name."""
    calls = collections.Counter()

    def counting(owner, name):
        call = getattr(owner, name)

        def wrapper(*args, **kwargs):
            calls[name] += 1
            return call(*args, **kwargs)
        return wrapper

    with monkeypatch.context() as patch:
        for owner, name in OPERATIONS:
            patch.setattr(owner, name, counting(owner, name))
        env.shard_step(env.shards[0])
    return calls


@pytest.mark.parametrize("task", tasks.names())
def test_the_step_graphs_operations_are_the_warp_calls_of_a_step(task, monkeypatch):
    env = tasks.make(task, num_envs=16, device="cpu", seed=0)
    try:
        found = nodes.step_nodes(env)
        calls = counted_calls(env, monkeypatch)
    finally:
        env.close()
    assert found.nodes == sum(calls.values()), (found, calls)
    assert sum(found.kernels.values()) == calls["launch"] + calls["launch_tiled"]
    assert any("end_step" in name for name in found.kernels), "the machinery's own kernel is named"


@pytest.mark.parametrize("tile_gemm", ["off", "on"])
def test_the_tile_path_replaces_the_dense_products_and_cholesky_by_one_tile_kernel(tile_gemm, monkeypatch):
    env = tasks.make("cart-three-pole-swingup", num_envs=16, device="cpu", seed=0, sim={"tile_gemm": tile_gemm})
    try:
        found = nodes.step_nodes(env)
        calls = counted_calls(env, monkeypatch)
    finally:
        env.close()
    assert found.nodes == sum(calls.values())
    dense = {"eval_dense_gemm_batched", "eval_dense_cholesky_batched"}
    tiled = [name for name in found.kernels if "tile" in name]
    if tile_gemm == "on":
        assert not dense & found.kernels.keys() and len(tiled) == 1 and calls["launch_tiled"] == 1
    else:
        assert found.kernels["eval_dense_gemm_batched"] == 2 and found.kernels["eval_dense_cholesky_batched"] == 1
        assert not tiled and calls["launch_tiled"] == 0


def test_the_report_names_the_count_and_the_kernels():
    env = tasks.make("cartpole-balance", num_envs=16, device="cpu", seed=0)
    try:
        found = nodes.step_nodes(env)
        text = nodes.report(found, env)
    finally:
        env.close()
    assert f"{found.nodes} Warp operations per env step" in text
    assert "eval_rigid_id" in text and "end_step" in text


def test_the_program_prints_both_paths(capsys):
    assert nodes.main(["--task", "cartpole-swingup", "--num-envs", "16", "--tile-gemm", "off", "on"]) == 0
    out = capsys.readouterr().out
    assert "sim.tile_gemm=off (tile path: False)" in out and "sim.tile_gemm=on (tile path: True)" in out
    assert out.count("Warp operations per env step") == 2


@pytest.mark.parametrize("tile_gemm", ["off", "on"])
def test_on_a_gpu_the_graphs_nodes_are_the_operations_warps_timing_records(tile_gemm):
    """On CUDA (``CARTPOLE_TEST_DEVICE=cuda:0``): the captured graph's nodes (Warp's DOT export) are the kernels,
    copies and memsets that Warp's timing API records in an uncaptured step."""
    if not DEVICE.startswith("cuda"):
        pytest.skip("needs a GPU: CARTPOLE_TEST_DEVICE=cuda:0 python -m pytest tests/test_nodes.py")
    env = tasks.make("cart-three-pole-swingup", num_envs=64, device=DEVICE, seed=0, sim={"tile_gemm": tile_gemm})
    try:
        found = nodes.step_nodes(env, steps=3)
    finally:
        env.close()
    assert found.nodes == round(sum(count for count, _ in found.device_us.values()))
    kernels = sum(count for name, (count, _) in found.device_us.items() if name.startswith("forward kernel"))
    assert kernels == sum(found.kernels.values())
