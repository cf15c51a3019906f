"""cathsim-bc: the student's network and loss, learning on tiny data, checkpoints, bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from cathsim_dmc.learning.supervised.bc import BCConfig, BCNetwork, bc_loss, load_bc_policy, save_bc, train_bc


def _demonstrations(episodes=4, steps=8, seed=0):
    """Images whose bright column encodes the action, as a stand-in for demonstrations."""
    rng = np.random.default_rng(seed)
    n = episodes * steps
    images = np.zeros((n, 1, 80, 80), np.uint8)
    actions = rng.uniform(-1, 1, size=(n, 2)).astype(np.float32)
    for i, (a, b) in enumerate(actions):
        images[i, 0, :, int((a + 1) * 39.5)] = 255
        images[i, 0, int((b + 1) * 39.5), :] = 128
    return images, actions, np.repeat(np.arange(episodes), steps)


def test_network_is_the_papers():
    net = BCNetwork()
    convs = [m for m in net.encoder.modules() if isinstance(m, torch.nn.Conv2d)]
    assert [(c.out_channels, c.kernel_size[0], c.stride[0]) for c in convs] == [(32, 8, 4), (64, 4, 2), (64, 3, 1)]
    linears = [m for m in net.modules() if isinstance(m, torch.nn.Linear)]
    assert [(layer.in_features, layer.out_features) for layer in linears] == [(2304, 512), (512, 2)]
    mean, log_std, z = net(torch.zeros(3, 1, 80, 80, dtype=torch.uint8))
    assert mean.shape == (3, 2) and log_std.shape == (3, 2) and z is None
    # The log-std is one learned parameter, the same for every image.
    assert net.log_std.requires_grad and torch.equal(log_std[0], log_std[2])


def test_loss_terms():
    net = BCNetwork()
    images, actions, _ = _demonstrations(1, 4)
    images, actions = torch.from_numpy(images), torch.from_numpy(actions)
    base, terms = bc_loss(net, images, actions, entropy_coef=0.0, l2_coef=0.0)
    with torch.no_grad():
        mean, log_std, _ = net(images)
    nll = -torch.distributions.Normal(mean, log_std.exp()).log_prob(actions).sum(-1).mean()
    assert base.item() == pytest.approx(nll.item(), rel=1e-5)
    # Entropy is rewarded (lowers the loss), L2 penalised. The Gaussian's entropy per action
    # dimension is 1/2 log(2 pi e) + log std; the L2 term is the sum of squared weights.
    entropy = float(np.log(2 * np.pi * np.e) + log_std[0].sum())
    l2 = sum(float((m.weight**2).sum()) for m in net.modules() if isinstance(m, (torch.nn.Conv2d, torch.nn.Linear)))
    assert terms["entropy"] == pytest.approx(entropy, rel=1e-5) and terms["l2"] == pytest.approx(l2, rel=1e-5)
    with_entropy, _ = bc_loss(net, images, actions, entropy_coef=0.1, l2_coef=0.0)
    assert with_entropy.item() == pytest.approx(base.item() - 0.1 * entropy, rel=1e-5)
    with_l2, _ = bc_loss(net, images, actions, entropy_coef=0.0, l2_coef=1e-3)
    assert with_l2.item() == pytest.approx(base.item() + 1e-3 * l2, rel=1e-5)


def test_student_overfits_a_handful_of_demonstrations():
    torch.set_num_threads(1)
    images, actions, episodes = _demonstrations(2, 4)
    cfg = BCConfig(epochs=150, batch_size=8, val_fraction=0.0, seed=0)  # the paper's lr, beta, lambda
    result = train_bc(images, actions, episodes, cfg)
    losses = [h["train_loss"] for h in result.history]
    assert losses[-1] < losses[0] - 0.5 and losses[-1] < min(losses[:10])
    with torch.no_grad():
        mean, _, _ = result.net(torch.from_numpy(images))
    error = np.abs(mean.numpy() - actions)
    assert error.max() < 0.02, error.max()


def test_distillation_regresses_z():
    images, actions, episodes = _demonstrations(2, 4)
    z = np.random.default_rng(1).normal(size=(len(actions), 16)).astype(np.float32)
    result = train_bc(images, actions, episodes, BCConfig(epochs=60, distill_coef=1.0, val_fraction=0.0), z=z)
    assert result.net.z_dim == 16
    assert result.history[-1]["train_z_mse"] < 0.2 * result.history[0]["train_z_mse"]


def test_checkpoint_acts_with_the_clipped_mean(tmp_path):
    from cathsim_dmc.agents.trained import CheckpointPolicy, make_policy

    net = BCNetwork()
    with torch.no_grad():
        net.mean.bias.copy_(torch.tensor([5.0, -0.25]))
        net.mean.weight.zero_()
    save_bc(net, tmp_path / "run", "pixels", {"renderer": "raster"})
    info = json.loads((tmp_path / "run" / "policy.json").read_text())
    assert info["algo"] == "bc" and info["obs"] == "pixels"
    policy = make_policy(str(tmp_path / "run"))
    assert isinstance(policy, CheckpointPolicy) and policy.image_options == {"renderer": "raster"}
    action = policy({"pixels": np.zeros((1, 80, 80), np.uint8)}, None)
    assert action.tolist() == [1.0, -0.25]
    assert load_bc_policy(tmp_path / "run" / "bc_policy.pt").image_key == "pixels"
    # The scripted policies' module loads no checkpoint: a path there says where to go.
    from cathsim_dmc.control import policies

    with pytest.raises(ValueError, match="cathsim_dmc.agents.trained.make_policy"):
        policies.make_policy(str(tmp_path / "run"))
    assert isinstance(make_policy("forward"), policies.ForwardPolicy)


def test_stacked_frames_are_the_images_before_in_the_same_episode():
    from cathsim_dmc.learning.datasets import stack_frames

    images = np.arange(7, dtype=np.uint8).reshape(7, 1, 1, 1) * np.ones((1, 1, 2, 2), np.uint8)
    episode = np.array([0, 0, 0, 0, 1, 1, 1])
    step = np.array([1, 2, 3, 4, 1, 2, 3])
    stacked = stack_frames(images, episode, step, 3)
    assert stacked.shape == (7, 3, 2, 2)
    # Oldest first; an episode's first image repeats where there is no earlier one, and
    # nothing crosses from episode 0 into episode 1.
    assert stacked[:, :, 0, 0].tolist() == [[0, 0, 0], [0, 0, 1], [0, 1, 2], [1, 2, 3], [4, 4, 4], [4, 4, 5], [4, 5, 6]]
    assert stack_frames(images, episode, step, 1) is images
    with pytest.raises(ValueError, match="step order"):
        stack_frames(images, episode, np.array([1, 2, 3, 4, 2, 3, 4]), 2)


def test_frame_stacking_student_keeps_its_buffer_per_episode(tmp_path):
    from cathsim_dmc.agents.trained import make_policy

    class Episode:  # what CheckpointPolicy reads of an environment: the step count
        def __init__(self):
            self.task = type("T", (), {"step_count": 0})()

    torch.manual_seed(0)
    save_bc(BCNetwork((2, 80, 80)), tmp_path / "run", "pixels", frames=2)
    policy = make_policy(str(tmp_path / "run"))
    assert policy.model.frames == 2
    net = policy.model.net
    dark, bright = np.zeros((1, 80, 80), np.uint8), np.full((1, 80, 80), 200, np.uint8)

    def expected(first, second):
        with torch.no_grad():
            return np.clip(net(torch.from_numpy(np.concatenate([first, second])[None]))[0][0].numpy(), -1, 1)

    env = Episode()
    np.testing.assert_allclose(policy({"pixels": dark}, env), expected(dark, dark), atol=1e-6)
    env.task.step_count = 1
    np.testing.assert_allclose(policy({"pixels": bright}, env), expected(dark, bright), atol=1e-6)
    env.task.step_count = 0  # a new episode: the buffer starts again from its first image
    np.testing.assert_allclose(policy({"pixels": bright}, env), expected(bright, bright), atol=1e-6)


def _bc(args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.bc", *args], cwd=cwd, capture_output=True, text=True, timeout=900
    )


def test_cli_trains_then_evaluates_and_cathsim_eval_loads_it(tmp_path):
    from cathsim_dmc.agents.collect import collect

    collect(
        tmp_path / "data",
        "bca",
        "type1",
        "expert",
        episodes=3,
        episodes_per_shard=3,
        seed=0,
        task_options={"max_steps": 10},
        show_progress=False,
    )
    result = _bc(
        [
            f"data={tmp_path}/data",
            "bc.epochs=3",
            "eval_episodes=1",
            "task.max_steps=5",
            "video=false",
            "progress_bar=false",
            f"hydra.run.dir={tmp_path}/bc",
        ],
        tmp_path,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    history = json.loads((tmp_path / "bc" / "history.json").read_text())
    assert len(history["epochs"]) == 3 and history["val_samples"] == 10
    assert json.loads((tmp_path / "bc" / "eval" / "metrics.json").read_text())["policy"] == "bc-pixels"
    ev = subprocess.run(
        [
            sys.executable,
            "-m",
            "cathsim_dmc.app.cli.eval",
            f"policy={tmp_path}/bc",
            "episodes=1",
            "task.max_steps=4",
            "video=false",
            f"hydra.run.dir={tmp_path}/eval",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert ev.returncode == 0, ev.stderr[-2000:]
    assert json.loads((tmp_path / "eval" / "metrics.json").read_text())["summary"]["episode_length"]["mean"] == 4


@pytest.mark.parametrize(
    "make, args, expected",
    [
        (None, [], "data="),
        (None, ["data=/no/such/dataset"], "/no/such/dataset"),
        ("empty_dir", [], "holds no dataset"),
        ("empty_file", [], "no samples"),
        ("bad_file", [], "not a readable"),
        (None, ["bc.image_key=depth"], "pixels"),
    ],
)
def test_bad_data_is_one_line_and_exit_2(tmp_path, make, args, expected):
    from cathsim_dmc.evaluation.trajectory import TrajectoryRecorder

    data = tmp_path / "data"
    data.mkdir()
    if make == "empty_file":
        recorder = TrajectoryRecorder("bca", "type1", np.zeros(3), record_observations=True)
        recorder.save(
            data / "shard_00000.npz",
            compress=False,
            obs_pixels=np.zeros((0, 1, 80, 80), np.uint8),
            start_obs_pixels=np.zeros((0, 1, 80, 80), np.uint8),
        )
    elif make == "bad_file":
        (data / "shard_00000.npz").write_bytes(b"not an npz")
    if make is not None:
        args = [f"data={data}"]
    elif args and not args[0].startswith("data="):
        args = [f"data={data}", *args]
    result = _bc([*args, f"hydra.run.dir={tmp_path}/bad"], tmp_path)
    assert result.returncode == 2, result.stderr[-2000:]
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and expected in lines[0] and "Traceback" not in result.stderr, result.stderr
