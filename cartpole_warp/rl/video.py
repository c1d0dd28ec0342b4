"""Clips of the policy while it trains (``train.py --video``, as Isaac Lab's ``--video --video_length
--video_interval``): every ``interval`` iterations the current deterministic policy plays ``length`` env steps on an
env of its own (one env of the task, built once), recorded as ``<run>/videos/iteration_<N>.mp4`` (and ``.gif``) by
the pictures play.py draws; the logger gets where each clip is. The training envs are not touched, so the iterations
between clips run as fast as without them.

    clips = TrainingVideo(training, length=200, interval=50)
    training.loop.on_iteration = clips             # called after each iteration
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..evaluation.rollouts import FirstEpisodesRun
from ..viz.record import Recorder, video_available

VIDEO_DIR = "videos"


class TrainingVideo:
    """``TrainingLoop.on_iteration``: a clip of ``length`` env steps of the policy after iteration ``it`` where ``it``
    counts a multiple of ``interval`` iterations from the run's first (the first iteration's included)."""

    def __init__(self, training, length: int, interval: int):
        cfg, self.record = training.cfg, training.loop.records[0]
        self.length, self.interval = length, interval
        self.first_iteration = self.record.next_iteration
        self.env = training.task.env_class(dataclasses.replace(cfg.env, num_envs=1))
        self.seed = cfg.env.seed
        self.out_dir = Path(training.run_dir) / VIDEO_DIR
        self.written: list[Path] = []

    def __call__(self, it: int, summary) -> None:
        if (it - self.first_iteration) % self.interval:
            return
        recorder = Recorder.of_env(self.env, self.out_dir, policy_view=False, name=f"iteration_{it + 1}", usd=False)
        try:
            FirstEpisodesRun(self.env, self.record.policy(), capture=False)(self.length, recorder, seed=self.seed)
        finally:
            self.record.learner.train_mode()
        clip = recorder.close()[-1]
        self.written.append(clip)
        writer = self.record.logger.writer
        relative = clip.relative_to(self.out_dir.parent)
        if hasattr(writer, "add_text"):  # TensorBoard: the clip's path at its iteration
            writer.add_text("Video", f"iteration {it + 1}: {relative}", it)
        if hasattr(writer, "save_video") and clip.suffix == ".mp4":  # W&B (rsl-rl's LogWriter)
            writer.save_video(clip, it)
        print(f"video: {relative}" + ("" if video_available() else " (no MP4: pip install 'cartpole_warp[video]')"),
              flush=True)

    def close(self):
        self.env.close()
