"""A thin layer over LimX's Python SDK (``limxsdk``, the ``.[robot]`` extra) for both sides of the link.

:class:`Link` is one ``limxsdk.robot.Robot.Robot`` of type PointFoot: the controller side
(``sim=False``: subscribe to state, IMU and joystick, publish commands) or the simulator side
(``sim=True``: subscribe to commands, publish state and IMU). Every callback copies its message
into numpy arrays with its arrival time (``time.perf_counter()``, s) under one lock and wakes
whoever waits in :meth:`Link.wait`.

On the wire (limxsdk 4.1.1, checked on 127.0.0.1): values are float32, the SDK stamps every
message itself (``stamp``: the sender's monotonic clock, ns), and ``motor_names`` is not carried:
the order of a message's arrays is the SDK's motor order, :meth:`Link.motor_names` on the
controller side.

Shutting down: the SDK has no close call, and it once crashed at interpreter exit. A process that
started a link therefore ends through :func:`leave`, which silences the callbacks, flushes the
output and exits with ``os._exit`` (no interpreter teardown under live SDK threads).
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np

from tron1cli.errors import Tron1Error

#: Motor order of the PF_TRON1A SDK (its ``getMotorNames()``); the simulator side reports none.
PF_TRON1A_MOTORS: tuple[str, ...] = (
    "abad_L_Joint",
    "hip_L_Joint",
    "knee_L_Joint",
    "abad_R_Joint",
    "hip_R_Joint",
    "knee_R_Joint",
)

_LINKS: list[Link] = []


def load_sdk():
    """(Robot, RobotType, datatypes) of limxsdk; Tron1Error when it is not installed."""
    os.environ.setdefault("ROBOT_TYPE", "PF_TRON1A")  # the SDK reads it to pick the robot's motors
    try:
        import limxsdk.datatypes as datatypes
        from limxsdk.robot.Robot import Robot
        from limxsdk.robot.RobotType import RobotType
    except ImportError as e:
        raise Tron1Error(
            f"LimX's SDK is not installed ({e}); install it with: pip install 'tron1cli[robot]'"
        ) from None
    return Robot, RobotType, datatypes


@contextlib.contextmanager
def _quiet_stdout():
    """File descriptor 1 to /dev/null for the duration (C-level prints included)."""
    sys.stdout.flush()
    saved = os.dup(1)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(null)


@dataclass
class Msg:
    """The newest message of one kind: arrays by field, arrival time ``t`` (perf_counter s), count."""

    fields: dict[str, np.ndarray]
    t: float
    count: int


class Link:
    """One SDK endpoint on ``ip``; see the module docstring."""

    def __init__(self, ip: str, sim: bool = False) -> None:
        Robot, RobotType, self.dt = load_sdk()
        self.sim = sim
        self.live = True
        self.cond = threading.Condition()
        self.newest: dict[str, Msg] = {}
        with _quiet_stdout():  # the SDK prints an INFO line on the C stdout, where --json goes
            self.robot = Robot(RobotType.PointFoot, sim)
            _LINKS.append(self)
            ok = self.robot.init(ip)
        if not ok:
            raise Tron1Error(f"the SDK could not connect to {ip}")

    # -- receiving --------------------------------------------------------------------------
    def _store(self, kind: str, **fields) -> None:
        now = time.perf_counter()
        if not self.live:
            return
        with self.cond:
            old = self.newest.get(kind)
            self.newest[kind] = Msg(fields, now, 1 if old is None else old.count + 1)
            self.cond.notify_all()

    def subscribe_robot(self, joystick: bool = False) -> None:
        """Controller side: keep the newest ``state`` (q, dq, tau), ``imu`` (quat, gyro, acc) and,
        with ``joystick``, ``joy`` (axes, buttons)."""
        f64 = np.asarray
        self.robot.subscribeRobotState(
            lambda m: self._store("state", q=f64(m.q, float), dq=f64(m.dq, float), tau=f64(m.tau, float))
        )
        self.robot.subscribeImuData(
            lambda m: self._store(
                "imu", quat=f64(m.quat, float), gyro=f64(m.gyro, float), acc=f64(m.acc, float)
            )
        )
        if joystick:
            self.robot.subscribeSensorJoy(
                lambda m: self._store("joy", axes=f64(m.axes, float), buttons=f64(m.buttons, float))
            )

    def subscribe_commands(self) -> None:
        """Simulator side: keep the newest ``cmd`` (mode, q, dq, tau, Kp, Kd)."""
        f64 = np.asarray

        def on_cmd(m) -> None:
            self._store(
                "cmd",
                mode=f64(m.mode, float),
                q=f64(m.q, float),
                dq=f64(m.dq, float),
                tau=f64(m.tau, float),
                kp=f64(m.Kp, float),
                kd=f64(m.Kd, float),
            )

        self.robot.subscribeRobotCmdForSim(on_cmd)

    def get(self, kind: str) -> Msg | None:
        with self.cond:
            return self.newest.get(kind)

    def wait(self, timeout_s: float) -> None:
        """Sleep until any message arrives or ``timeout_s`` passes."""
        with self.cond:
            self.cond.wait(timeout=timeout_s)

    # -- sending ----------------------------------------------------------------------------
    def motor_names(self) -> list[str]:
        names = list(self.robot.getMotorNames())
        return names or list(PF_TRON1A_MOTORS)

    def publish_command(self, q, dq, tau, kp, kd, names: list[str]) -> None:
        """Controller side: one joint command, arrays in the SDK's motor order (mode 0)."""
        c = self.dt.RobotCmd()
        n = len(names)
        c.mode = [0] * n
        c.q, c.dq, c.tau = [float(x) for x in q], [float(x) for x in dq], [float(x) for x in tau]
        c.Kp, c.Kd = [float(x) for x in kp], [float(x) for x in kd]
        c.motor_names = list(names)
        self.robot.publishRobotCmd(c)

    def publish_state(self, q, dq, tau) -> None:
        """Simulator side: joint state in the SDK's motor order."""
        s = self.dt.RobotState()
        s.q, s.dq, s.tau = [float(x) for x in q], [float(x) for x in dq], [float(x) for x in tau]
        s.motor_names = []
        self.robot.publishRobotStateForSim(s)

    def publish_imu(self, quat, gyro, acc) -> None:
        """Simulator side: orientation (w, x, y, z), angular velocity (rad/s) and acceleration (m/s^2)."""
        m = self.dt.ImuData()
        m.quat, m.gyro, m.acc = [float(x) for x in quat], [float(x) for x in gyro], [float(x) for x in acc]
        self.robot.publishImuDataForSim(m)

    def close(self) -> None:
        """Stop handing messages on (the SDK's own threads live until :func:`leave`)."""
        self.live = False


def in_use() -> bool:
    """Whether this process created an SDK endpoint."""
    return bool(_LINKS)


def leave(code: int) -> None:
    """End a process that used the SDK: callbacks silenced, output flushed, ``os._exit(code)``."""
    for link in _LINKS:
        link.close()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)
