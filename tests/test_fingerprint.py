"""``tools.fingerprint``: the digests of a run's checkpoints, the same for the same fixed-seed run on one machine and
different where one weight, one optimizer moment or the seed differs; the comparison's lines and exit code."""

import json

import pytest
import torch

from cartpole_warp.tools import fingerprint


def test_a_digest_sees_every_tensor_and_nothing_else():
    checkpoint = {"model_state_dict": {"w": torch.arange(6.0).reshape(2, 3)},
                  "optimizer_state_dict": {"state": {0: {"exp_avg": torch.zeros(3)}}}, "iter": 5,
                  "infos": {"history": [{"train_time_s": 1.25}]}}
    base = fingerprint.tensor_digest(checkpoint)
    assert base == fingerprint.tensor_digest({**checkpoint, "iter": 6, "infos": {"history": []}}), "no wall times"
    flipped = torch.arange(6.0).reshape(2, 3)
    flipped.view(torch.int32)[0, 0] ^= 1  # the smallest change a float can take
    assert fingerprint.tensor_digest({**checkpoint, "model_state_dict": {"w": flipped}}) != base
    moment = {"state": {0: {"exp_avg": torch.tensor([0.0, 0.0, 1e-30])}}}
    assert fingerprint.tensor_digest({**checkpoint, "optimizer_state_dict": moment}) != base
    assert fingerprint.tensor_digest({**checkpoint, "model_state_dict": {"w": torch.arange(6.0).reshape(3, 2)}}) != base


def test_compare_names_what_differs_and_exits_1(tmp_path, capsys):
    same = {"balance": {"model_0.pt": "a", "model_best.pt": "b"}}
    (tmp_path / "a.json").write_text(json.dumps(same))
    (tmp_path / "b.json").write_text(json.dumps({"balance": {"model_0.pt": "a", "model_best.pt": "c"}}))
    assert fingerprint.main(["--compare", str(tmp_path / "a.json"), str(tmp_path / "a.json")]) == 0
    assert capsys.readouterr().out == "bitwise the same: balance\n"
    assert fingerprint.main(["--compare", str(tmp_path / "a.json"), str(tmp_path / "b.json")]) == 1
    assert capsys.readouterr().out == "balance: model_best.pt differ\n"
    assert fingerprint.differences(same, {}) == ["balance: model_0.pt, model_best.pt differ"]


def test_unknown_runs_and_a_tree_without_train_py_are_one_line(tmp_path, capsys):
    for argv, message in ((["--runs", "cartwheel"], "unknown runs cartwheel"),
                          (["--tree", str(tmp_path)], f"--tree {tmp_path} holds no train.py")):
        with pytest.raises(SystemExit) as stop:
            fingerprint.main(argv)
        assert stop.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.slow
def test_the_same_run_gives_the_same_digests_and_another_seed_others():
    first = fingerprint.fingerprint_run(fingerprint.REPO, fingerprint.RUNS["balance"])
    assert sorted(first) == ["model_0.pt", "model_25.pt", "model_best.pt"]
    assert fingerprint.fingerprint_run(fingerprint.REPO, fingerprint.RUNS["balance"]) == first
    other = fingerprint.fingerprint_run(fingerprint.REPO, [*fingerprint.RUNS["balance"], "--seed", "1"])
    assert all(other[name] != first[name] for name in first)
