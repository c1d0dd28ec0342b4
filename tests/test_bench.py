"""tools.bench: a row per setting of the sweep, SolverFeatherstone's path named in each."""

from cartpole_warp.tools import bench


def test_a_row_per_path_of_the_sweep_and_the_tasks_own_by_default(capsys):
    assert bench.main(["--task", "cart-two-pole-swingup", "--num-envs", "64", "--seconds", "0.05",
                       "--tile-gemm", "off", "on"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("featherstone")]
    assert [row[1] for row in rows] == ["off", "on"] and all(float(row[-2].replace(",", "")) > 0 for row in rows)
    assert bench.main(["--task", "cart-two-pole-swingup", "--num-envs", "64", "--seconds", "0.05"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("featherstone")]
    assert [row[1] for row in rows] == ["off"], "the chain's own path: the dense one (tasks.DENSE_PATH)"
