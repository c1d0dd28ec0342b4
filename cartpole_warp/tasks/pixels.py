"""The cart-pole tasks from pixels: the balance, the swing-up and the double pole, seen by one camera per env
(``CameraConfig``), with the same physics, rewards, ends, resets and solved rules as their state twins. The policy
sees the last frames (``env.camera``), the critic the task's state (an asymmetric actor-critic: ``rl.image_model``)."""

import dataclasses

from ..settings.presets import TrainSettings
from . import Configure, TaskSettings, balance, compose, dense_path, double_pole, register, swingup


def pixel_settings(cfg: TrainSettings):
    """What a policy from pixels changes in its twin's training settings: symmetry off (its signs mirror states, not
    images), a 64 x 64 actor after the encoder."""
    cfg.agent.algorithm.symmetry = False
    cfg.agent.actor.hidden_dims = [64, 64]


BALANCE_CAMERA = {"eye_m": (5.0, 0.0, 0.5), "target_m": (0.0, 0.0, 0.5), "fov_rad": 1.0}
"""The rail's +-3 m (where the balance ends) and the upright pole, seen from the pole's side."""
SWINGUP_CAMERA = {"eye_m": (4.0, 0.0, 0.0), "target_m": (0.0, 0.0, 0.0), "fov_rad": 0.95}
"""dm_control's +-1.8 m slider and the pole hanging or up, seen from the pole's side."""
DOUBLE_POLE_CAMERA = {"eye_m": (6.0, 0.0, 1.0), "target_m": (0.0, 0.0, 1.0), "fov_rad": 1.0, "frame_stack": 5}
"""The rail's +-3 m (where the double pole ends) and both poles up to their 2 m tip, seen from the poles' side; five
frames, since at about 10 cm a pixel the poles' speeds show only over a longer span than three frames."""
CNN_KL = 0.01
"""The adaptive learning rate's KL target for an encoder learning a balance: at the state tasks' looser target the
rate climbs to rsl-rl's cap (1e-2) and the action noise collapses before the pole is held (docs/benchmarks.md)."""


def balance_settings(cfg: TrainSettings):
    """A balance from pixels learns in fewer iterations from 16 steps per env and two passes over each rollout than
    from its twin's 8 steps and one pass, at the encoder's KL target (``CNN_KL``)."""
    cfg.agent.num_steps_per_env = 16
    cfg.agent.algorithm.num_learning_epochs, cfg.agent.algorithm.desired_kl = 2, CNN_KL


def double_pole_settings(cfg: TrainSettings):
    """The double pole from pixels: two passes over each rollout, twice the entropy bonus (with the state twin's, two
    seeds of four did not solve), the wider encoder with overlapping 8x8 windows it was measured with, and more
    iterations than its twin."""
    cfg.agent.max_iterations = 1900
    cfg.agent.actor.cnn.output_channels, cfg.agent.actor.cnn.kernel_size = [16, 32, 32], [8, 4, 3]
    algorithm = cfg.agent.algorithm
    algorithm.num_learning_epochs, algorithm.desired_kl, algorithm.entropy_coef = 2, CNN_KL, 0.01


def from_pixels(task, name: str, image: str, camera: dict, gym_id: str, summary: str,
                own: Configure | None = None):
    """``task`` seen by a camera (``image`` 'rgb' or 'depth', ``camera`` its other settings), registered as ``name``:
    its twin's settings, then ``pixel_settings``, then its ``own``, on the dense path; the twin's device settings are
    about its MLP and do not come along, its settings for a learner do."""
    def view(cfg: TrainSettings):
        cfg.env.camera = dataclasses.replace(cfg.env.camera, image=image, **camera)

    settings = TaskSettings(common=compose(task.settings.common, pixel_settings, own, dense_path, view),
                            for_learner=task.settings.for_learner)
    return register(dataclasses.replace(task, name=name, settings=settings, summary=summary, gym_ids={gym_id: None}))


from_pixels(balance.TASK, "cartpole-balance-rgb", "rgb", BALANCE_CAMERA, "cartpole_warp/CartpoleBalanceRGB-v0",
            "the balance from 64x64 colour frames (3 stacked; the critic sees the state)", balance_settings)
from_pixels(balance.TASK, "cartpole-balance-depth", "depth", BALANCE_CAMERA, "cartpole_warp/CartpoleBalanceDepth-v0",
            "the balance from 64x64 depth frames (metres, 3 stacked; the critic sees the state)", balance_settings)
from_pixels(swingup.TASK, "cartpole-swingup-rgb", "rgb", SWINGUP_CAMERA, "cartpole_warp/CartpoleSwingupRGB-v0",
            "the swing-up from 64x64 colour frames (3 stacked; the critic sees the state)")
from_pixels(double_pole.TASK, "cart-double-pole-balance-rgb", "rgb", DOUBLE_POLE_CAMERA,
            "cartpole_warp/CartDoublePoleRGB-v0",
            "the double pole from 64x64 colour frames (5 stacked; the critic sees the state)", double_pole_settings)
