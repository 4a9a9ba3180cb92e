"""Depth over UDP (sim-robot -> deploy-robot) and deploy-robot's depth safety, without the SDK."""

from __future__ import annotations

import socket
import time
from dataclasses import replace

import numpy as np
import pytest

from tron1cli.deploy.depth_link import HEADER, DepthSender, UdpDepth, decode, encode, parse_address
from tron1cli.deploy.sdk import PF_TRON1A_MOTORS, Msg
from tron1cli.errors import UsageError


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_frame_round_trip_is_millimetres_with_holes_kept():
    img = np.array([[0.3, 1.2344], [2.9996, 0.0], [np.nan, np.inf]], dtype=np.float32)
    packet = encode(img, seq=7, t_capture=1.5)
    assert len(packet) == HEADER.size + 2 * img.size
    seq, t, back = decode(packet)
    assert (seq, t, back.shape, back.dtype) == (7, 1.5, (3, 2), np.float32)
    np.testing.assert_allclose(back, [[0.3, 1.234], [3.0, 0.0], [0.0, 0.0]], atol=1e-6)
    assert len(encode(np.zeros((60, 80)), 0, 0.0)) == 9616  # one datagram per 80 x 60 frame
    assert decode(b"T1D0" + packet[4:]) is None and decode(packet[:-2]) is None and decode(b"x") is None


def test_address_forms():
    assert parse_address("10.0.0.2:5000") == ("10.0.0.2", 5000)
    assert parse_address(":5000") == ("127.0.0.1", 5000) and parse_address("5000") == ("127.0.0.1", 5000)
    for bad in ("host:port", "1.2.3.4:0", "1.2.3.4:70000"):
        with pytest.raises(UsageError):
            parse_address(bad)


def test_receiver_keeps_the_newest_frame_of_its_size():
    port = free_port()
    rx = UdpDepth(port, 60, 80, host="127.0.0.1")
    rx.start()
    tx = DepthSender("127.0.0.1", port)
    try:
        assert rx.newest() is None and rx.age_s() == np.inf
        tx.send(np.full((30, 40), 1.0), 0, 0.0)  # another size: dropped
        for seq in (1, 2):
            tx.send(np.full((60, 80), float(seq)), seq, 0.0)
        tx.send(np.full((60, 80), 9.0), 1, 0.0)  # older than the newest: dropped
        t0 = time.monotonic()
        while rx.received + rx.foreign + rx.late < 4 and time.monotonic() - t0 < 5.0:
            time.sleep(0.01)
        assert (rx.received, rx.foreign, rx.late) == (2, 1, 1)
        assert np.all(rx.newest() == 2.0) and 0.0 <= rx.age_s() < 5.0
        with pytest.raises(UsageError, match="cannot listen"):
            UdpDepth(port, 60, 80, host="192.0.2.1")  # an address this machine does not have
    finally:
        tx.close()
        rx.close()


class StandingRobot:
    """A fake controller-side link: a robot hanging still in the default pose, messages at 500 Hz."""

    def __init__(self) -> None:
        self.count = 0
        self.commands: list[tuple[np.ndarray, np.ndarray]] = []

    def motor_names(self) -> list[str]:
        return list(PF_TRON1A_MOTORS)

    def get(self, kind: str):
        if kind == "joy":
            return None
        self.count += 1
        n = len(PF_TRON1A_MOTORS)
        now = time.perf_counter()
        if kind == "state":
            return Msg({"q": np.zeros(n), "dq": np.zeros(n), "tau": np.zeros(n)}, now, self.count)
        imu = {"quat": np.array([1.0, 0, 0, 0]), "gyro": np.zeros(3), "acc": np.zeros(3)}
        return Msg(imu, now, self.count)

    def wait(self, timeout_s: float) -> None:
        time.sleep(min(timeout_s, 0.002))

    def publish_command(self, q, dq, tau, kp, kd, names) -> None:
        self.commands.append((np.asarray(kp).copy(), np.asarray(kd).copy()))


class ScriptedDepth:
    """A depth source whose frames stop ``stop_after_s`` after start (None: never; 0: no frame)."""

    def __init__(self, rows: int, cols: int, stop_after_s: float | None) -> None:
        self.frame = np.full((rows, cols), 1.0, dtype=np.float32)
        self.stop_after_s = stop_after_s
        self.t0 = None

    def start(self) -> None:
        self.t0 = time.monotonic()

    def _last(self) -> float | None:
        """Arrival time of the newest frame (frames every 1/30 s)."""
        now = time.monotonic()
        if self.stop_after_s == 0:
            return None
        end = now if self.stop_after_s is None else min(now, self.t0 + self.stop_after_s)
        return self.t0 + np.floor((end - self.t0) * 30.0) / 30.0

    def newest(self):
        return None if self._last() is None else self.frame

    def age_s(self) -> float:
        last = self._last()
        return np.inf if last is None else time.monotonic() - last

    def close(self) -> None:
        pass


@pytest.fixture(scope="module")
def perceptive_policy(tmp_path_factory):
    """A tiny untrained perceptive student (checkpoint), as deploy-robot would load it."""
    from tron1cli.config.presets import perceptive
    from tron1cli.policy.runtime import load_policy
    from tron1cli.train.runner import Trainer, run_config

    d = tmp_path_factory.mktemp("perceptive")
    preset = replace(perceptive("stairs"), num_envs=4, steps_per_env=2, hidden=(16,))
    trainer = Trainer(d, run_config(preset, nthread=1))
    trainer.save()
    trainer.close()
    return load_policy(d / "checkpoints" / "latest.pt")


@pytest.mark.parametrize(
    "stop_after_s,ended,line",
    [(None, "duration", None), (0.6, "lost depth", "no depth frame for"), (0, "lost depth", "within 0.3 s")],
)
def test_perceptive_policy_waits_for_depth_and_trips_when_frames_stop(
    perceptive_policy, stop_after_s, ended, line
):
    from tron1cli.deploy.robot import RobotConfig, RobotController

    link = StandingRobot()
    depth = ScriptedDepth(*perceptive_policy.depth_hw, stop_after_s=stop_after_s)
    cfg = RobotConfig(duration_s=1.0, ramp_s=0.1, connect_timeout_s=0.3, damping_s=0.05)
    ctrl = RobotController(perceptive_policy, cfg, link, depth)
    depth.start()
    rep = ctrl.run()
    assert rep["ended"] == ended
    if line is None:
        assert rep["safety_trip"] is None and rep["policy_steps"] == 50
        assert rep["depth_age_ms_p99"] < 1e3 * cfg.depth_timeout_s
    else:
        assert line in rep["safety_trip"] and rep["policy_steps"] < 50
    kp, kd = link.commands[-1]
    assert np.all(kp == 0) and np.all(kd > 0)  # it ends in the damping command either way


def test_perceptive_policy_without_a_depth_source_is_refused(perceptive_policy):
    from tron1cli.deploy.robot import RobotConfig, RobotController
    from tron1cli.errors import Tron1Error

    with pytest.raises(Tron1Error, match="needs a depth source"):
        RobotController(perceptive_policy, RobotConfig(), StandingRobot(), None)


def test_sim_robot_camera_sends_what_the_training_renderer_sees():
    from tron1cli.deploy.sim_robot import SimRobot, SimRobotConfig
    from tron1cli.env import sensors

    port = free_port()
    rx = UdpDepth(port, 60, 80, host="127.0.0.1")
    rx.start()
    sim = SimRobot(SimRobotConfig(terrain="stairs", level=3, noise=False, depth_to=("127.0.0.1", port)), None)
    cam = sim.camera
    try:
        cam.start()
        cam.tick(0.0)
        cam.tick(0.01)  # within the frame period: no second frame
        t0 = time.monotonic()
        while rx.received < 1 and time.monotonic() - t0 < 30.0:
            time.sleep(0.01)
        assert rx.received == 1 and cam.seq == 1
        d = sim.data
        want = sensors.render_depth(
            sim.bank.heights[sim.tile : sim.tile + 1],
            np.zeros(1, np.int64),
            d.cam_xpos[cam.cam_id][None],
            d.cam_xmat[cam.cam_id].reshape(1, 3, 3),
            sensors.DepthCamera(),
            sim.bank.res,
        )[0]
        np.testing.assert_allclose(rx.newest(), want, atol=5e-4)  # millimetre quantisation
        assert np.median(want) < sensors.DepthCamera().far  # it looks at the stairs, not the sky
    finally:
        cam.close()
        rx.close()
