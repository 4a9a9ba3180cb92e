"""Domain randomisation (paper Table III) and pushes: per-env, seeded, each term switchable.

Every env owns its MjModel, so physical parameters are written into that env's model at reset
and hold for the episode; the randomiser samples each term for all the envs being reset at once
and hands the physics one (k, ...) array per model field (:meth:`BatchedPhysics.write_models`;
the warp backend writes its batched device rows from it in one operation):

=================  =====================================  ==========================================
term               range                                  where it acts
=================  =====================================  ==========================================
payload            -1 .. 3 kg                             base body mass
com_shift          +/-3, +/-2, +/-3 cm (x, y, z)          base body CoM
friction           0.4 .. 1.2                             sliding friction of ground and feet
restitution        0.25 .. 0.75                           the feet's impacts above the bounce threshold
kp, kd             x 0.8 .. 1.2                           position actuators' stiffness and damping
motor_strength     x 0.8 .. 1.2                           actuator gains and torque limit together
delay              0 .. 20 ms                             the new joint target reaches the motors
                                                          only after this, the old one holds before
camera             +/-10 mm position, +/-1 deg pitch      the depth camera's mount (per env)
camera_fov         +/-1 deg field of view                 the depth camera's focal length (per env):
                                                          vertical FOV 58 +/- 1 deg, the horizontal
                                                          with it (87 +/- 1.3 deg), train and eval
=================  =====================================  ==========================================

Restitution, as the paper's simulator has it (README, "Restitution"): PhysX combines the robot's
sampled restitution e with the terrain material's (``ground_restitution``) by the combine mode of
higher priority (the terrain's ``multiply`` over the robot's ``average``), and applies the result
only to contacts that close faster than the bounce threshold (Isaac Lab: 0.5 m/s); slower
contacts and resting contacts do not bounce. MuJoCo has no restitution: a contact is a damped
spring. So every contact keeps MuJoCo's critically damped default, and a foot that is in the air
and descending faster than the threshold gets, for its impact (:data:`IMPACT_STEPS` policy steps
while it stays down), a stiffer, underdamped contact whose measured rebound is the combined e
(:meth:`Randomizer.gate_restitution`, :func:`impact_damping_ratio`); the ground's ``solmix`` is
made negligible so that the foot's damping ratio is the contact's. The
earlier mapping (``restitution_model="damping"``: every contact of the feet and the ground
underdamped with the sampled e, resting contacts included) stays available.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tron1cli.env import robot
from tron1cli.env.physics import BatchedPhysics

ALL_TERMS = (
    "payload",
    "com_shift",
    "friction",
    "restitution",
    "kp",
    "kd",
    "motor_strength",
    "delay",
    "camera",
    "camera_fov",
)


#: natural frequency (rad/s) of a foot's contact during its impact: twice the nominal contact's
#: (1 / 0.02 s), so that the bounce is over within about 30 ms of touchdown and the foot sinks
#: half as deep (measured by a foot sphere dropped at 0.7-1.3 m/s: 6-12 mm at e = 0.75)
IMPACT_OMEGA = 100.0
#: policy steps a foot's impact keeps its low damping ratio: the step in which the descending foot
#: is armed and the next ones while it stays on the ground
IMPACT_STEPS = 3
#: the impact contact's damping ratio (ascending) and the restitution it gives a foot sphere
#: dropped at 0.7, 1.0 and 1.3 m/s at :data:`IMPACT_OMEGA` (mean; checked in
#: tests/test_restitution.py): MuJoCo's discrete soft contact departs from the spring-damper's
#: exp(-pi zeta / sqrt(1 - zeta^2)) and rebounds about 0.14 even critically damped, so a wanted e
#: maps to zeta through this measured curve
IMPACT_ZETA = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.6, 0.7, 0.8)
IMPACT_E = (0.861, 0.734, 0.642, 0.571, 0.503, 0.438, 0.387, 0.35, 0.315, 0.281, 0.225, 0.19, 0.152)


def _check_terms(terms: tuple[str, ...]) -> None:
    unknown = set(terms) - set(ALL_TERMS)
    if unknown:
        raise ValueError(f"unknown randomisation terms {sorted(unknown)}; choose from {', '.join(ALL_TERMS)}")


#: PhysX's combine modes of two materials' coefficients
COMBINE_MODES: dict[str, Callable[[np.ndarray, float], np.ndarray]] = {
    "average": lambda a, b: 0.5 * (a + b),
    "min": np.minimum,
    "multiply": lambda a, b: a * b,
    "max": np.maximum,
}


def combined_restitution(e_robot: np.ndarray, e_ground: float, mode: str) -> np.ndarray:
    """Restitution of a robot-ground contact in PhysX: ``mode`` (the terrain's combine mode, which
    outranks the robot's ``average``) applied to the two materials' coefficients."""
    return np.asarray(COMBINE_MODES[mode](np.asarray(e_robot, dtype=np.float64), e_ground), dtype=np.float64)


@dataclass(frozen=True)
class RandomizationConfig:
    """Which Table III terms are on (``terms``) and their ranges (units in the names).

    Restitution (see the module docstring): ``ground_restitution`` the terrain material's
    coefficient (1.0 in LimX's TRON1 Isaac Lab configuration, 0.0 in Isaac Lab's own locomotion
    terrain), ``restitution_combine`` PhysX's combine mode, ``bounce_threshold_mps`` the closing
    speed (m/s) below which nothing bounces; ``restitution_model`` ``impact`` (as PhysX) or
    ``damping`` (the earlier mapping: every foot contact underdamped).
    """

    terms: tuple[str, ...] = ()
    payload_kg: tuple[float, float] = (-1.0, 3.0)
    com_shift_m: tuple[float, float, float] = (0.03, 0.02, 0.03)
    friction: tuple[float, float] = (0.4, 1.2)
    restitution: tuple[float, float] = (0.25, 0.75)
    kp_scale: tuple[float, float] = (0.8, 1.2)
    kd_scale: tuple[float, float] = (0.8, 1.2)
    motor_strength: tuple[float, float] = (0.8, 1.2)
    delay_s: tuple[float, float] = (0.0, 0.02)
    camera_pos_m: float = 0.01
    camera_pitch_deg: float = 1.0
    camera_fov_deg: float = 1.0
    ground_restitution: float = 1.0
    restitution_combine: str = "multiply"
    bounce_threshold_mps: float = 0.5
    restitution_model: str = "impact"

    def __post_init__(self) -> None:
        _check_terms(self.terms)
        if self.restitution_combine not in COMBINE_MODES:
            raise ValueError(f"restitution_combine must be one of {', '.join(COMBINE_MODES)}")
        if self.restitution_model not in ("impact", "damping"):
            raise ValueError("restitution_model must be 'impact' or 'damping'")
        if not 0.0 <= self.ground_restitution <= 1.0 or not self.bounce_threshold_mps >= 0.0:
            raise ValueError("ground_restitution must lie in [0, 1] and bounce_threshold_mps be >= 0")

    @classmethod
    def table_iii(cls, skip: tuple[str, ...] = ()) -> RandomizationConfig:
        """Every term of the paper's Table III, but those in ``skip``."""
        _check_terms(skip)
        return cls(terms=tuple(t for t in ALL_TERMS if t not in skip))

    def on(self, term: str) -> bool:
        return term in self.terms


def damping_ratio_for_restitution(e: np.ndarray) -> np.ndarray:
    """Damping ratio zeta of a damped spring whose coefficient of restitution is ``e`` in (0, 1)."""
    L = np.log(e)
    return -L / np.sqrt(np.pi**2 + L**2)


def impact_damping_ratio(e: np.ndarray) -> np.ndarray:
    """Damping ratio of the impact contact whose measured restitution is ``e`` (:data:`IMPACT_E`);
    1 (no bounce) below MuJoCo's own rebound."""
    e = np.asarray(e, dtype=np.float64)
    zeta = np.interp(-e, [-x for x in IMPACT_E], IMPACT_ZETA)
    return np.where(e < IMPACT_E[-1], 1.0, zeta)


def impact_solref(zeta: np.ndarray, omega: float) -> np.ndarray:
    """MuJoCo ``solref`` rows (k, 2) with damping ratios ``zeta`` (k,) and natural frequency
    ``omega`` (rad/s): MuJoCo's contact stiffness is 1 / (timeconst zeta)^2, so the time constant
    is 1 / (omega zeta)."""
    zeta = np.asarray(zeta, dtype=np.float64)
    return np.stack([1.0 / (omega * zeta), zeta], axis=-1)


class Randomizer:
    """Samples and applies the configured terms to the envs' own models, through ``physics``.

    Attributes (N rows): ``delay_steps`` physics substeps before a new target acts,
    ``camera_offset`` (N, 3) m in the base frame, ``camera_pitch`` (N,) rad added to the mount,
    ``camera_fov_delta`` (N,) deg added to the camera's vertical field of view.
    """

    def __init__(self, cfg: RandomizationConfig, physics: BatchedPhysics, sim_dt: float, nsub: int) -> None:
        self.cfg = cfg
        self.physics = physics
        self.sim_dt = sim_dt
        self.nsub = nsub
        n = physics.n
        m0 = physics.models[0]
        self.base = m0.body("base").id
        self.nominal_mass = float(m0.body_mass[self.base])
        self.nominal_ipos = m0.body_ipos[self.base].copy()
        self.contact_geoms = [m0.geom(g).id for g in ("foot_L_geom", "foot_R_geom")]
        self.ground = m0.geom("ground").id
        self.delay_steps = np.zeros(n, dtype=np.int64)
        self.camera_offset = np.zeros((n, 3))
        self.camera_pitch = np.zeros(n)
        self.camera_fov_delta = np.zeros(n)
        self.values: dict[str, np.ndarray] = {}
        #: per env: damping ratio of a foot's impact above the bounce threshold (1: no bounce)
        self.impact_zeta = np.ones(n)
        self._bouncy = np.zeros((n, len(self.contact_geoms)), dtype=bool)
        self._impact_left = np.zeros((n, len(self.contact_geoms)), dtype=np.int64)
        self.nominal_solref = m0.geom_solref[self.contact_geoms[0]].copy()
        self._gated = cfg.on("restitution") and cfg.restitution_model == "impact"
        if self._gated:  # the foot's damping ratio, not a mix with the ground's, sets the contact's
            physics.write_models(np.arange(n), "geom_solmix", (self.ground,), np.full(n, 1e-9))

    def apply(self, ids: np.ndarray, rng: np.random.Generator) -> None:
        """Draw new parameters for envs ``ids`` and write them into their models."""
        c, k = self.cfg, len(ids)
        if k == 0 or not c.terms:
            return
        u = lambda lo_hi, size=k: rng.uniform(lo_hi[0], lo_hi[1], size)  # noqa: E731
        ones = np.ones(k)
        payload = u(c.payload_kg) if c.on("payload") else np.zeros(k)
        shift = (
            rng.uniform(-1.0, 1.0, (k, 3)) * np.array(c.com_shift_m)
            if c.on("com_shift")
            else np.zeros((k, 3))
        )
        friction = u(c.friction) if c.on("friction") else None
        zeta = None
        if c.on("restitution"):
            e = u(c.restitution)
            if c.restitution_model == "damping":
                zeta = damping_ratio_for_restitution(e)
            else:
                e_eff = combined_restitution(e, c.ground_restitution, c.restitution_combine)
                self.impact_zeta[ids] = impact_damping_ratio(e_eff)
                self._bouncy[ids] = False
                self._impact_left[ids] = 0
                nominal = np.broadcast_to(self.nominal_solref, (k, 2))
                self.physics.write_models(ids, "geom_solref", (self.contact_geoms,), nominal)
        kp = u(c.kp_scale) if c.on("kp") else ones
        kd = u(c.kd_scale) if c.on("kd") else ones
        strength = u(c.motor_strength) if c.on("motor_strength") else ones
        if c.on("delay"):
            self.delay_steps[ids] = np.minimum(np.round(u(c.delay_s) / self.sim_dt).astype(int), self.nsub)
        if c.on("camera"):
            self.camera_offset[ids] = rng.uniform(-c.camera_pos_m, c.camera_pos_m, (k, 3))
            self.camera_pitch[ids] = np.radians(rng.uniform(-c.camera_pitch_deg, c.camera_pitch_deg, k))
        if c.on("camera_fov"):
            self.camera_fov_delta[ids] = rng.uniform(-c.camera_fov_deg, c.camera_fov_deg, k)
        write = self.physics.write_models
        touching = [self.ground, *self.contact_geoms]
        write(ids, "body_mass", (self.base,), self.nominal_mass + payload)
        write(ids, "body_ipos", (self.base,), self.nominal_ipos + shift)
        if friction is not None:
            write(ids, "geom_friction", (touching, 0), friction)
        if zeta is not None:
            write(ids, "geom_solref", (touching,), np.stack([np.full(k, 0.02), zeta], axis=-1))
        write(ids, "actuator_gainprm", (slice(None), 0), robot.KP * kp * strength)
        bias = np.stack([-robot.KP * kp * strength, -robot.KD * kd * strength], axis=-1)
        write(ids, "actuator_biasprm", (slice(None), [1, 2]), bias)
        limit = robot.TORQUE_LIMIT * strength
        write(ids, "actuator_forcerange", (slice(None),), np.stack([-limit, limit], axis=-1))
        self.values = {
            "payload": payload,
            "friction": friction if friction is not None else np.full(k, np.nan),
            "kp": kp,
            "kd": kd,
            "motor_strength": strength,
        }

    def gate_restitution(self, foot_in_contact: np.ndarray, foot_vz: np.ndarray) -> None:
        """Before a policy step: a foot in the air descending faster than the bounce threshold
        (``foot_vz`` (N, F) m/s, world z) bounces on its impact, which may start in this step
        and go on into the next (:data:`IMPACT_STEPS` policy steps in all); every other foot
        contact stays critically damped. Writes the feet's contact softness of the envs where a
        foot changed, in one array."""
        if not self._gated:
            return
        fast = -foot_vz > self.cfg.bounce_threshold_mps
        arm = ~foot_in_contact & fast & (self.impact_zeta < 1.0)[:, None]
        self._impact_left = np.where(
            arm, IMPACT_STEPS, np.where(foot_in_contact, np.maximum(self._impact_left - 1, 0), 0)
        )
        want = self._impact_left > 0
        envs = np.flatnonzero((want != self._bouncy).any(axis=1))
        if envs.size:  # both feet of those envs: the unchanged one is written its own value
            impact = impact_solref(self.impact_zeta[envs], IMPACT_OMEGA)  # (k, 2)
            solref = np.where(want[envs, :, None], impact[:, None, :], self.nominal_solref)  # (k, F, 2)
            self.physics.write_models(envs, "geom_solref", (self.contact_geoms,), solref)
        self._bouncy = want


@dataclass(frozen=True)
class PushConfig:
    """External wrench pushes on the base, world frame.

    force_n, torque_nm: symmetric range per axis (x, y, z); duration_s: how long a push lasts;
    interval_s: range of the time between pushes.
    """

    enabled: bool = False
    force_n: tuple[float, float, float] = (50.0, 50.0, 50.0)
    torque_nm: tuple[float, float, float] = (5.0, 5.0, 5.0)
    duration_s: float = 0.2
    interval_s: tuple[float, float] = (3.0, 6.0)

    @classmethod
    def moderate(cls) -> PushConfig:
        """The paper's moderate disturbances: +/-50 N and +/-5 N m along x, y, z."""
        return cls(enabled=True)

    @classmethod
    def extreme(cls) -> PushConfig:
        """The paper's extreme disturbances: +/-400 N and +/-20 N m."""
        return cls(enabled=True, force_n=(400.0, 400.0, 400.0), torque_nm=(20.0, 20.0, 20.0))


class Pusher:
    """Per-env push timers; writes the active wrench (N, 6) into ``wrench`` each step."""

    def __init__(self, cfg: PushConfig, num_envs: int, wrench: np.ndarray) -> None:
        self.cfg = cfg
        self.wrench = wrench
        self.next_push = np.full(num_envs, np.inf)
        self.push_left = np.zeros(num_envs)

    def reset(self, ids: np.ndarray, rng: np.random.Generator) -> None:
        self.push_left[ids] = 0.0
        self.wrench[ids] = 0.0
        if self.cfg.enabled:
            self.next_push[ids] = rng.uniform(*self.cfg.interval_s, len(ids))

    def tick(self, dt: float, rng: np.random.Generator) -> np.ndarray:
        """Advance by ``dt`` (s): start due pushes, end finished ones; returns envs pushed now."""
        if not self.cfg.enabled:
            return np.empty(0, dtype=np.int64)
        c = self.cfg
        self.push_left -= dt
        ended = self.push_left <= 0.0
        self.wrench[ended] = 0.0
        self.next_push -= dt
        due = np.flatnonzero(self.next_push <= 0.0)
        if len(due):
            k = len(due)
            self.wrench[due, :3] = rng.uniform(-1.0, 1.0, (k, 3)) * np.array(c.force_n)
            self.wrench[due, 3:] = rng.uniform(-1.0, 1.0, (k, 3)) * np.array(c.torque_nm)
            self.push_left[due] = c.duration_s
            self.next_push[due] = rng.uniform(*c.interval_s, k)
        return due
