"""Clips while training (``rl/video.py``, ``train.py --video``): written every --video-interval iterations into the
run folder, named in TensorBoard at their iteration, played on an env of their own (the training is bitwise what it
is without them)."""

from pathlib import Path

import torch
from conftest import call_main, requires_mp4
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator


def train(log_dir: Path, *flags) -> Path:
    result = call_main("train", "--num-envs", 64, "--max-iterations", 3, "--logger", "tensorboard", "--log-dir",
                       log_dir, *flags)
    assert result.returncode == 0, result.stdout + result.stderr
    (run,) = (log_dir / "rsl_rl" / "cartpole-balance").iterdir()
    return run


def test_clips_are_written_every_interval_named_in_tensorboard_and_leave_training_alone(tmp_path):
    requires_mp4()
    import imageio.v2 as imageio

    run = train(tmp_path / "video", "--video", "--video-interval", 2, "--video-length", 5)
    clips = sorted(path.name for path in (run / "videos").iterdir())
    assert clips == ["iteration_1.gif", "iteration_1.mp4", "iteration_3.gif", "iteration_3.mp4"]
    assert sum(1 for _ in imageio.get_reader(run / "videos" / "iteration_3.mp4")) == 6, "the reset and 5 steps"
    events = EventAccumulator(str(run), size_guidance={"tensors": 0}).Reload()
    texts = [(event.step, event.tensor_proto.string_val[0].decode()) for event in events.Tensors("Video/text_summary")]
    assert texts == [(0, "iteration 1: videos/iteration_1.mp4"), (2, "iteration 3: videos/iteration_3.mp4")]
    plain = train(tmp_path / "plain")
    with_clips = torch.load(run / "model_2.pt", weights_only=False)["actor_state_dict"]
    without = torch.load(plain / "model_2.pt", weights_only=False)["actor_state_dict"]
    assert all(torch.equal(with_clips[name], without[name]) for name in without), "the same training"


def test_clip_settings_must_make_sense(tmp_path):
    for flag in ("--video-length", "--video-interval"):
        result = call_main("train", "--video", flag, 0, "--log-dir", tmp_path)
        assert result.returncode == 2 and result.stderr == f"error: {flag} must be >= 1, got 0\n", result.stderr
