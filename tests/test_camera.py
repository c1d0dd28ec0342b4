"""Camera observations (``camera.py``, ``CameraConfig``, the pixel tasks): what the frames show, against the camera's
geometry; the frame stack; bad settings; the asymmetric actor-critic; a training from pixels with its exports."""

import copy
import math

import numpy as np
import pytest
import torch
from conftest import call_main

import cartpole_warp
from cartpole_warp.engine import camera
from cartpole_warp.settings.config import ConfigError

POLE_FACE_X_M = 0.12 + 0.02
"""The Isaac stage's pole (``usd/cartpole.usda``): its hinge 0.12 m beside the cart on +x, a box 0.04 m thick in x
from z = -0.03 to 0.97 m: its face towards a camera on +x."""
CENTERED = {"eye_m": (5.0, 0.0, 0.5), "target_m": (0.0, 0.0, 0.5), "fov_rad": 1.0, "width_px": 65, "height_px": 65,
            "min_width_px": 0.0}
"""A camera on +x at the pole's mid-height, an odd frame (its middle pixel's ray is the optical axis), the stage's
own shape sizes."""


def upright(env, cart_pos_m=0.0, pole_angle_rad=0.0):
    """Every env at rest at ``cart_pos_m`` with the pole at ``pole_angle_rad``; returns the observations."""
    states = torch.tensor([cart_pos_m, 0.0, pole_angle_rad, 0.0], device=env.device).repeat(env.num_envs, 1)
    return env.set_state(states).cpu()


def test_depth_is_the_distance_to_the_pole_and_the_pole_moves_with_the_cart(make):
    env = make(1, task_name="cartpole-balance-depth", camera=CENTERED | {"frame_stack": 1})
    middle = 32
    depth_m = upright(env)[0, 0]
    assert depth_m[middle, middle] == pytest.approx(5.0 - POLE_FACE_X_M, abs=1e-4), "along the axis to the face"
    assert depth_m[middle, 0] == 0.0, "nothing there: rays that hit nothing read 0"
    half_width_m = (5.0 - POLE_FACE_X_M) * math.tan(CENTERED["fov_rad"] / 2)  # half the frame, at the pole
    for cart_pos_m in (0.5, -0.8):
        row = upright(env, cart_pos_m)[0, 0, middle]
        columns = torch.nonzero((row > 4.5) & (row < 5.0)).flatten().float()
        expected = middle + cart_pos_m / half_width_m * 32.5  # the image's right is the world's +y (the rail)
        assert len(columns) > 0 and abs(columns.mean().item() - expected) <= 1.0, (cart_pos_m, columns, expected)


def test_a_fixed_state_renders_the_same_frame_bitwise_and_another_state_another(make):
    env, other = (make(4, task_name="cartpole-balance-rgb", camera={"width_px": 64, "height_px": 64})
                  for _ in range(2))
    frames = upright(env, 0.3, 0.2)
    assert frames.dtype == torch.uint8 and frames.shape == (4, 9, 64, 64)
    assert torch.equal(frames, upright(other, 0.3, 0.2)), "another env, the same state: the same pixels"
    assert all(torch.equal(frames[0], frames[k]) for k in range(4)), "every env's camera sees its own robot alike"
    tilted = upright(env, 0.3, -0.2)
    assert not torch.equal(tilted, frames)
    changed = (tilted != frames).any(dim=1)[0]
    rows = torch.nonzero(changed.any(dim=1)).flatten()
    assert rows.min() < 32 - 5, "the pole's upper part moved: pixels well above the rail changed"
    assert frames.max() > 100 and (frames == 0).float().mean() > 0.5, "a lit robot on a black background"


@pytest.mark.parametrize("task", ["cartpole-balance-rgb", "cart-three-pole-swingup"])
def test_thin_shapes_are_drawn_at_least_the_minimum_width_and_no_two_alike(task, make):
    """Where two faces coincide, a ray draws whichever the BVH lists first, and Newton's CUDA build lists an env's
    shapes in an atomic counter's order: the same state drew a few pixels differently from one build to the next."""
    env = make(3, task_name=task, camera={"image": "rgb", "width_px": 64, "height_px": 64, "min_width_px": 4.0})
    cfg, model = env.cfg.camera, env.cameras[0].scene.model
    pixel_m = 2 * math.dist(cfg.eye_m, cfg.target_m) * math.tan(cfg.fov_rad / 2) / cfg.height_px
    boxes = model.shape_type.numpy() == 7  # newton.GeoType.BOX
    world, half_m = model.shape_world.numpy(), model.shape_scale.numpy()
    for env_index in range(3):
        thinnest_m = half_m[boxes & (world == env_index)].min(axis=1)
        assert (thinnest_m >= 4.0 * pixel_m / 2 - 1e-7).all(), "at least min_width_px wide"
        assert len(np.unique(thinnest_m)) == len(thinnest_m), f"two shapes of env {env_index} equally thick"


@pytest.mark.parametrize("size_px", [64, 63], ids=["words", "pixels"])  # 63 x 63 pixels: no whole words
def test_frames_stack_shift_each_step_and_refill_at_the_reset(size_px, make):
    env, witness = (make(8, task_name="cartpole-balance-rgb", camera={"width_px": size_px, "height_px": size_px})
                    for _ in range(2))
    channels = 3
    before = upright(env, 0.1, 0.05)
    assert all(torch.equal(before[:, :channels], before[:, k:k + channels]) for k in (3, 6)), "a reset repeats"
    after = env.step(torch.full((8, 1), 0.7, device=env.device))[0].cpu()
    assert torch.equal(after[:, :6], before[:, 3:]), "the older frames move back by one"
    newest = witness.set_state(env.get_state_observations()).cpu()  # the state after the step, as a reset
    assert torch.equal(after[:, 6:], newest[:, 6:]), "the newest frame is the state after the step"
    assert torch.equal(after[:, 6:], rgb_planes(env.cameras[0].frame)), "the newest frame is the view's colours"
    assert not torch.equal(after[:, 6:], before[:, 6:])
    env.episode_length_buf = torch.full((8,), env.max_episode_length - 1, dtype=torch.int32, device=env.device)
    obs, _, _, truncated, info = env.step(torch.zeros(8, 1, device=env.device))
    obs = obs.cpu()
    assert truncated.all()
    assert torch.equal(info["final_obs"][:, :6].cpu(), after[:, 3:]), "the final stack shifted like any other"
    assert all(torch.equal(obs[:, :channels], obs[:, k:k + channels]) for k in (3, 6)), "the new episode's start"
    assert torch.equal(obs[:, :channels], rgb_planes(env.cameras[0].first_frame)), "its colours"


def rgb_planes(frame) -> torch.Tensor:
    """(N, 3, H, W) uint8 red, green and blue planes of a view's packed RGBA pixels (N, H, W), decoded here."""
    rgba = torch.from_numpy(frame.numpy().astype(np.int64))
    return torch.stack([(rgba >> (8 * c)) & 255 for c in range(3)], dim=1).to(torch.uint8)


def test_the_envs_that_reset_are_drawn_alike_in_passes_of_a_few_views(make):
    """On CUDA the views of the envs that reset are drawn a few at a time (``Camera.views_per_pass``); every env that
    resets must get its own new first frame whichever pass draws it."""
    envs = [make(8, task_name="cartpole-balance-rgb", sim={"capture": "off"},
                 camera={"width_px": 32, "height_px": 32}) for _ in range(2)]
    for env, views_per_pass in zip(envs, (8, 3)):
        env.cameras[0] = camera.Camera(env.shards[0].scene, env.cfg.camera, env.device, views_per_pass=views_per_pass)
    results = []
    for env in envs:
        states = torch.tensor([[1.0, 0.0, 0.15, 0.0]] * 8, device=env.device)  # drawn unlike a reset's state
        before = env.set_state(states).cpu()
        env.episode_length_buf = torch.full((8,), env.max_episode_length - 1, dtype=torch.int32, device=env.device)
        obs, _, terminated, truncated, info = env.step(torch.zeros(8, 1, device=env.device))
        assert (terminated | truncated).all(), "all 8 reset: 3 passes of 3, 3 and 2 views"
        assert not torch.equal(obs.cpu()[:, 6:], before[:, 6:]), "the new episodes are drawn, not the old frames"
        results.append((obs.cpu(), info["final_obs"].cpu()))
    assert torch.equal(results[0][0], results[1][0]) and torch.equal(results[0][1], results[1][1])


BAD_CAMERAS = [
    ({"width_px": 0}, "camera.width_px"),
    ({"height_px": -4}, "camera.height_px"),
    ({"fov_rad": 0.0}, "camera.fov_rad"),
    ({"fov_rad": math.pi}, "camera.fov_rad"),
    ({"frame_stack": 0}, "camera.frame_stack"),
    ({"eye_m": (math.nan, 0.0, 0.5)}, "camera.eye_m"),
    ({"eye_m": (0.0, 0.0, 0.5), "target_m": (0.0, 0.0, 0.5)}, "camera.target_m"),
    ({"eye_m": (0.0, 0.0, 5.0), "target_m": (0.0, 0.0, 0.0)}, "looks straight up or down"),
    ({"image": "infrared"}, "camera.image"),
]


@pytest.mark.parametrize(("camera", "message"), BAD_CAMERAS)
def test_bad_camera_settings_are_config_errors_naming_the_field(camera, message):
    with pytest.raises(ConfigError, match=message):
        cartpole_warp.tasks.make("cartpole-balance-rgb", num_envs=2, camera=camera)


def test_more_cameras_than_memory_holds_is_an_error_with_the_estimate_before_allocating():
    with pytest.raises(ConfigError, match=r"1,000,000 cameras .* need about [\d,.]+ GB \([\d,.]+ kB per env\)"):
        cartpole_warp.tasks.make("cartpole-balance-rgb", num_envs=1_000_000, camera={"width_px": 512,
                                                                                    "height_px": 512})


def test_the_actor_sees_frames_and_the_critic_the_state(make):
    from cartpole_warp.rl.policies import to_rsl_rl
    from cartpole_warp.settings.agent import RunnerConfig
    from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv

    env = RslRlVecEnv(make(4, task_name="cartpole-balance-rgb"))
    obs = env.get_observations()
    assert obs["policy"].shape == (4, 9, 12, 16) and obs["policy"].dtype == torch.uint8
    assert torch.equal(obs["critic"], env.env.get_state_observations())  # on the env's device, as rsl-rl's storage
    assert env.obs_mirror is None, "the mirror signs are the state's, not the pictures'"
    cfg = to_rsl_rl(RunnerConfig(), mirror=False, images=True)
    assert cfg["obs_groups"] == {"actor": ["policy"], "critic": ["critic"]}
    assert cfg["actor"]["class_name"].endswith(":ImageModel") and cfg["critic"]["class_name"] == "MLPModel"
    assert cfg["actor"]["cnn_cfg"] == {"output_channels": [8, 16, 16], "kernel_size": [4, 4, 3],
                                       "stride": [4, 2, 1], "activation": "elu"}
    assert cfg["actor"]["precision"] == "bfloat16"


def train(log_dir, seed=3):
    result = call_main("train", "--task", "cartpole-balance-rgb", "--num-envs", 16, "--max-iterations", 2,
                       "--seed", seed, "--eval.num-envs", 4, "--logger", "none", "--log-dir", log_dir)
    assert result.returncode == 0, result.stdout + result.stderr
    (run,) = (log_dir / "rsl_rl" / "cartpole-balance-rgb").iterdir()
    return run


BFLOAT16_RTOL = 0.05
"""How far a GPU's policy (its encoder in bfloat16, ``agent.actor.cnn.precision``) may act from the same checkpoint in
float32 (the CPU's arithmetic, and the exports'): bfloat16 keeps 8 significant bits, so each value the encoder computes
is off by up to 2^-8 relative, and three convolutions and the MLP compound it."""


def test_a_policy_from_pixels_trains_and_its_exports_act_like_the_checkpoint_on_frames(tmp_path, make):
    """The exports compute as the checkpoint's actor does in float32 (to float rounding), on every device; what play
    runs on a GPU, the encoder in bfloat16, acts within ``BFLOAT16_RTOL`` of it, and on the CPU exactly as it."""
    import onnxruntime

    from cartpole_warp.rl.policies import deterministic, load_actor
    from cartpole_warp.rl.runs import load_config
    from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv

    run = train(tmp_path / "a")
    cfg = load_config(run)
    env = make(5, task_name="cartpole-balance-rgb", camera={"width_px": 64, "height_px": 64})
    frames = env.reset(seed=4)[0]
    for _ in range(3):
        frames, *_ = env.step(torch.rand(5, 1, device=env.device) * 2 - 1)
    actor = load_actor(RslRlVecEnv(env), cfg.agent, run / "model_1.pt")
    with torch.no_grad():
        played = deterministic(actor)(frames).cpu().numpy()
        frames = frames.cpu()
        expected = deterministic(copy.deepcopy(actor).to("cpu"))(frames).numpy()
    if env.device == "cpu":
        np.testing.assert_array_equal(played, expected)
    else:
        np.testing.assert_allclose(played, expected, rtol=BFLOAT16_RTOL, atol=BFLOAT16_RTOL * np.abs(expected).max())
    session = onnxruntime.InferenceSession(str(run / "exported" / "policy.onnx"))
    (onnx_input,) = session.get_inputs()
    assert onnx_input.type == "tensor(uint8)" and onnx_input.shape[1:] == [9, 64, 64]
    (actions,) = session.run(None, {"obs": frames.numpy()})
    np.testing.assert_allclose(actions, expected, rtol=1e-5, atol=1e-5)
    scripted = torch.jit.load(str(run / "exported" / "policy.pt"))(frames).detach().numpy()
    np.testing.assert_allclose(scripted, expected, rtol=1e-5, atol=1e-5)
    program = torch.export.load(run / "exported" / "policy.pt2").module()(frames).detach().numpy()
    np.testing.assert_allclose(program, expected, rtol=1e-5, atol=1e-5)
    played = call_main("play", "--headless", "--run", run, "--num-envs", 2, "--steps", 6)
    assert played.returncode == 0, played.stdout + played.stderr
    from PIL import Image

    with Image.open(run / "play" / "policy_view.gif") as view, Image.open(run / "play" / "cartpole.gif") as side:
        assert view.n_frames == side.n_frames == 4 and view.width > side.width, "the camera frames beside the view"
        panels = []
        for frame in (0, 3):
            view.seek(frame)
            panels.append(np.asarray(view.convert("RGB"))[:, side.width:])
    assert not np.array_equal(*panels), "each step's own frames (not the last ones, over and over)"
    again = torch.load(train(tmp_path / "b") / "model_1.pt", weights_only=False)["actor_state_dict"]
    first = torch.load(run / "model_1.pt", weights_only=False)["actor_state_dict"]
    assert all(torch.equal(first[name], again[name]) for name in first), "same seed, same run"
