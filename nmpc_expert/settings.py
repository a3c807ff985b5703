"""Settings of the NMPC expert: one typed, frozen, validated dataclass.

The constraint limits are not settings: they are the environment's (one source per limit),
read when used: the physical ones from the model's parameters (``uvms_env.models``,
``parameters.toml`` ``[limits]``), the manipulability bound and the pitch margin from the
task's constraint definitions (``uvms_env.task.constraints``). ``NMPCSettings`` only holds
how much tighter the expert keeps them, as fractions of (or margins beyond) those limits:
``vehicle_speed``, ``joint_speed``, ``joint_position``, ``pitch_margin`` and
``manipulability_eps`` are derived properties.

May import: numpy, the standard library, ``uvms_env.models``, ``uvms_env.scenarios``
(the default control period) and ``uvms_env.task.constraints``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from uvms_env.models import load_parameters
from uvms_env.scenarios import Scenario

# ``task_constraints`` as a module, its constants read at use: the definition there stays
# the only one (redefining it moves the expert's bounds too).
from uvms_env.task import constraints as task_constraints

# The control period is the scenario's (one definition: ``Scenario.period``'s default).
_SCENARIO_PERIOD: float = {f.name: f.default for f in fields(Scenario)}["period"]
# The safety filter's horizon: 3 periods (0.36 s) instead of the expert's 5. Its
# constraints are on speeds (relative degree one in the inputs) and on angles behind the
# back-off (``NMPCSettings.backoff``), so a short look-ahead suffices (measurements:
# docs/notes/2026-11-23-safety-filter-tuning.md).
FILTER_HORIZON = 3
EXPERT_HORIZON = 5  # the paper's Np
# The horizons one compiled controller library holds (``nmpc_expert.ocp``): the expert's
# default and the filter's, so that the filter's first use compiles nothing new.
LIBRARY_HORIZONS = (FILTER_HORIZON, EXPERT_HORIZON)


@dataclass(frozen=True)
class NMPCSettings:
    """Tuning and limits of one robot's NMPC (defaults: the paper's values where it has them)."""

    horizon: int = EXPERT_HORIZON
    """Np, number of shooting intervals (paper: 5)."""
    period: float = _SCENARIO_PERIOD
    """h [s], sampling time and shooting interval: the scenarios' control period (the
    paper's); it must equal the scenario's (``LocalController`` checks)."""
    substeps: int = 2
    """RK4 substeps per interval: with the joints' armature and friction the fastest mode
    has a time constant of ~0.05 s; one RK4 step of 0.12 s sits at the edge of RK4's
    stability region (|lambda h| ~ 2.4 < 2.79), two give a safe margin."""
    q_x: float = 0.8
    """Qx = q_x I6: weight on the object pose error (paper 0.8)."""
    q_v: float = 0.4
    """Qv = q_v I6: weight on the object twist error (paper 0.4)."""
    p_x: float = 0.8
    """Px = p_x I6: terminal weight on the object pose error (paper 0.8)."""
    r_u: float = 0.3
    """R = r_u I8 on the *normalized* inputs a = tau / tau_max in [-1, 1] (paper 0.3)."""
    input_reference: str = "steady_state"
    """What R penalizes: "zero" (|a|^2_R, literally the paper) or "steady_state"
    (|a - a_ss|^2_R with a_ss the nominal input that holds the reference twist against
    drag and weight; docs/expert.md). With "zero" the input cost outweighs the speed
    error at the paper's weights and the team crawls."""
    attitude_from_waypoint: bool = True
    """Pose reference attitude = the active waypoint's (True) or the navigation law's
    propagated Euler angles (False); see ``reference``."""
    attitude_tip_speed: float = 0.0
    """[m/s] 0: the pose reference's attitude is the active waypoint's at once. Above 0
    (with ``attitude_from_waypoint``): it moves toward the waypoint's at no more than
    attitude_tip_speed / R rad/s per Euler angle, R the object's bounding radius (known
    before the task), and the twist reference's angular speed is capped alike, so that a
    waypoint's turn asks about this speed of the object's farthest point whatever its
    length (``reference.AttitudeSlew``); an object where that rate is not below the
    navigation law's own attitude rate keeps the waypoint's attitude. Why: on a long bar a
    turn asks the end robots for omega R, which their teammates feel only through the bar
    (docs/results/expert.md)."""
    angular_backoff: float = 0.5
    """Tighter back-off for the joint rates and the vehicle's angular rates: the local
    model ignores the internal wrench, whose effect on these rates shows within one period
    (tuning: docs/expert.md, "Tuning record")."""
    offset_gain: float = 0.5
    """Gain L of the rate-offset estimator (0 disables it): each period the robot filters
    its own one-step error, e <- e + L (zeta_meas - zeta_pred - e), and the speed
    constraints of the whole horizon apply to zeta_pred + e (why: docs/expert.md)."""
    offset_limit: float = 1.0
    """|e| clip as a fraction of each speed limit: one bad measurement cannot move a bound
    by more than this (why 1.0: docs/expert.md, "Tuning record")."""
    disturbance_observer: bool = True
    """Offset-free local prediction (False: the paper's controller, with the rate-offset
    estimator above on the speed bounds only): the innovation is integrated, d <- d + L_d
    (zeta_meas - zeta_pred), and the prediction adds d to every interval's end velocity,
    F(x_k, a_k) + [0; d]; the rate-offset bound shift is then off, the speed bounds are
    tightened by ``margin_gain`` times the innovation's recent spread instead (docs/expert.md,
    the observer controller)."""
    observer_gain: float = 0.5
    """L_d, the observer's integral gain per period (0 < L_d <= 1)."""
    observer_limit: float = 5.0
    """|d| clip per period, in speed limits (one bad measurement cannot run away). Where
    the teammates hold a joint the estimate settles at up to ~3 limits (the model's
    input gain is off, not only its offset)."""
    observer_input_gain: float = 0.5
    """g: the steady-state input reference a_ss (``input_reference``: what R pulls the
    inputs towards) moves by the input that cancels g * d on the vehicle's linear rates,
    through the last linearization's input gain (0: off; why only those rates and only
    part of d: docs/expert.md, the observer controller)."""
    observer_input_limit: float = 0.3
    """|a_ss shift| clip per input (normalized), the same anti-runaway as ``observer_limit``."""
    observer_anti_windup: bool = False
    """Freeze the estimate of a rate whose input was saturated in the direction the
    innovation asks for (conditional integration; why off: docs/expert.md)."""
    margin_gain: float = 4.0
    """k: the speed bounds move inwards by k * sigma, sigma the innovation's RMS (an
    exponential moving average of its square, weight ``margin_forgetting``)."""
    margin_forgetting: float = 0.1
    """Weight of the newest squared innovation in sigma's moving average (0 < w <= 1)."""
    margin_limit: float = 0.3
    """The adaptive margin never exceeds this fraction of a speed limit."""
    margin_initial: float = 0.3
    """The margin before any measurement (a fraction of each speed limit; the moving
    average starts from the variance that gives it): at the start every robot
    accelerates at once and the observer knows nothing yet."""
    start_margin: float = 0.0
    """A floor under the adaptive margin at the episode's start, as a fraction in [0, 1)
    of each speed bound (``backoff`` or ``angular_backoff`` of the limit), falling
    linearly to 0 over ``start_margin_s`` (observer controller only). Why: on a long bar
    every robot's first plans accelerate at once and the chain turns their disagreement
    into joint speed before any innovation is measured (docs/results/expert.md); a
    margin_limit that high for the whole episode leaves the team too little speed to
    hold the bar."""
    start_margin_s: float = 0.0
    """[s] How long ``start_margin`` takes to fall to 0 (0: no start margin)."""
    input_step: float | None = 0.15
    """delta: hard bound on the normalized input's change per period, |a_0 - a_prev| <=
    delta and along the plan (None: none, the paper's); why: docs/expert.md. A full
    reversal takes 2 / delta periods (1.6 s at 0.15)."""
    goal_integral_gain: float = 0.5
    """k_i [1/s] of the integral action at the goal (``reference.GoalIntegral``; 0 disables
    it): a steady current or buoyancy error the model lacks leaves no position offset. Every
    robot integrates its estimate of the shared object, so the robots agree silently."""
    goal_integral_radius: float = 0.5
    """The integral runs only while the object is this close to the last waypoint [m]."""
    goal_integral_limit: float = 2.0
    """|k_i I| clip per position axis [m] (anti-windup)."""
    goal_integral_angle_limit: float = 0.8
    """|k_i I| clip per Euler angle [rad] (anti-windup; why 0.8: docs/expert.md, "Tuning
    record")."""
    slack_l1: float = 100.0
    """Exact-penalty weight (per unit of normalized violation) of the soft state constraints."""
    slack_l2: float = 10.0
    """Quadratic penalty on the same slacks (keeps the QP strictly convex)."""
    vehicle_speed_fraction: tuple[float, float] = (1.0, 1.0)
    """The expert's vehicle speed limits per body axis (``vehicle_speed``) as fractions of
    the model's (translational, rotational), each in (0, 1]; 1: the environment's limits."""
    joint_speed_fraction: float = 1.0
    """The expert's |qd_m| limit (``joint_speed``) as a fraction of the model's, in (0, 1]."""
    joint_position_fraction: float = 1.0
    """The expert's |q_m| limit (``joint_position``) as a fraction of the model's, in (0, 1]."""
    joint_position_penalty: tuple[float, float] | None = None
    """(L1, L2) slack penalties of the four joint-position rows; None: ``slack_l1`` and
    ``slack_l2``, as every row. With a tighter ``joint_position_fraction`` and no L1, the
    rows become a pull toward the joints' mid-range (a posture cost that starts at the
    band's edge) instead of a wall at the limit: a robot whose arm sits at its bound has a
    reason to move its vehicle so that the arm leaves it (docs/results/expert.md)."""
    pitch_margin_extra: float = 0.0
    """[rad] the expert's pitch margin (``pitch_margin``) beyond the environment's
    representation margin, >= 0."""
    manipulability_factor: float = 1.0
    """The expert's manipulability bound (``manipulability_eps``) as a multiple of the
    environment's, >= 1."""
    backoff: float = 0.85
    """The NMPC uses backoff * limit for speeds and joint positions, so that model error
    and the soft-constraint slack do not reach the true limit."""
    piece_fraction: float = 0.0
    """What object a robot's local model carries, in [0, 1]: 0, its load share c_i of the
    whole object at the centroid (the paper's); 1, the piece of the object nearest its
    grasp that holds c_i of its length; between, a blend (``ObjectModel.carried_parameters``).
    What each does on the bars and rings: docs/results/expert.md."""
    piece_lever_start: float = 0.0
    """[m] With ``piece_lever_full`` > 0, the fraction a robot uses grows with its own lever
    arm |l_i| (``piece_fraction_for``): 0 up to this, ``piece_fraction`` from
    ``piece_lever_full`` on, linear between. Why: the share's moment about the grasp,
    c_i l_i x f, is what the piece removes, and it grows with |l_i|."""
    piece_lever_full: float = 0.0
    """[m] Where the lever ramp reaches ``piece_fraction``; 0: no ramp, every robot uses
    ``piece_fraction``."""
    fallback_after_ms: float = 50.0
    """A decision slower than this counts as 'slow' in the stats (never blocks)."""

    @property
    def vehicle_speed(self) -> tuple[float, float]:
        """Limits per body axis: translational [m/s], rotational [rad/s] (the model's
        ``vehicle_linear_speed``, ``vehicle_angular_speed`` times ``vehicle_speed_fraction``)."""
        lim = load_parameters().limits
        f_lin, f_ang = self.vehicle_speed_fraction
        return (f_lin * lim.vehicle_linear_speed, f_ang * lim.vehicle_angular_speed)

    @property
    def joint_speed(self) -> float:
        """|qd_m| limit [rad/s]: the model's ``joint_speed`` times ``joint_speed_fraction``."""
        return self.joint_speed_fraction * load_parameters().limits.joint_speed

    @property
    def joint_position(self) -> float:
        """|q_m| limit [rad]: the model's ``joint_position`` times ``joint_position_fraction``."""
        return self.joint_position_fraction * load_parameters().limits.joint_position

    @property
    def pitch_margin(self) -> float:
        """|theta_O|, |theta_i| <= pi/2 - pitch_margin [rad] (object and vehicle pitch, the
        representation singularity): the environment's ``REPRESENTATION_MARGIN`` plus
        ``pitch_margin_extra``."""
        return task_constraints.REPRESENTATION_MARGIN + self.pitch_margin_extra

    @property
    def manipulability_eps(self) -> float:
        """Lower bound of det(Jbar Jbar^T): the environment's ``MANIPULABILITY_EPS`` times
        ``manipulability_factor``."""
        return self.manipulability_factor * task_constraints.MANIPULABILITY_EPS

    def piece_fraction_for(self, lever: float) -> float:
        """The piece fraction of a robot whose grasp is ``lever`` [m] from the object's
        origin: ``piece_fraction``, ramped by ``piece_lever_start``/``piece_lever_full``."""
        if self.piece_lever_full == 0:
            return self.piece_fraction
        start, full = self.piece_lever_start, self.piece_lever_full
        return self.piece_fraction * min(1.0, max(0.0, (lever - start) / (full - start)))

    def start_floor(self, elapsed: float) -> float:
        """The margin floor ``elapsed`` seconds into the episode, as a fraction of each
        speed bound (``start_margin``)."""
        if self.start_margin_s == 0:
            return 0.0
        return self.start_margin * max(0.0, 1.0 - elapsed / self.start_margin_s)

    def __post_init__(self) -> None:
        if self.horizon < 1 or self.substeps < 1:
            raise ValueError("horizon and substeps must be >= 1")
        if self.period <= 0:
            raise ValueError(f"period must be > 0, got {self.period}")
        for name in ("q_x", "q_v", "p_x", "r_u", "slack_l1", "slack_l2"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.r_u <= 0:
            raise ValueError("r_u must be > 0 (the QP needs a positive definite input weight)")
        if not self.attitude_tip_speed >= 0 or not np.isfinite(self.attitude_tip_speed):
            raise ValueError(f"attitude_tip_speed must be >= 0, got {self.attitude_tip_speed}")
        if self.attitude_tip_speed > 0 and not self.attitude_from_waypoint:
            raise ValueError(
                "attitude_tip_speed slews the waypoint's attitude: it needs "
                "attitude_from_waypoint=True"
            )
        if not 0 <= self.piece_fraction <= 1:
            raise ValueError(f"piece_fraction must lie in [0, 1], got {self.piece_fraction}")
        if not 0 <= self.start_margin < 1 or not self.start_margin_s >= 0:
            raise ValueError(
                "start_margin must lie in [0, 1) and start_margin_s be >= 0, got "
                f"start_margin={self.start_margin}, start_margin_s={self.start_margin_s}"
            )
        if (self.start_margin > 0) != (self.start_margin_s > 0):
            raise ValueError(
                "start_margin and start_margin_s go together (both 0, or both above), got "
                f"start_margin={self.start_margin}, start_margin_s={self.start_margin_s}"
            )
        if self.start_margin > 0 and not self.disturbance_observer:
            raise ValueError(
                "start_margin floors the observer controller's adaptive margin: it needs "
                "disturbance_observer=True"
            )
        start, full = self.piece_lever_start, self.piece_lever_full
        if full != 0 and not 0 <= start < full:
            raise ValueError(
                "piece_lever_full must be 0 (no ramp) or above piece_lever_start >= 0, got "
                f"piece_lever_start={start}, piece_lever_full={full}"
            )
        if full == 0 and start != 0:
            raise ValueError(f"piece_lever_start={start} needs piece_lever_full > it")
        if self.input_reference not in ("zero", "steady_state"):
            raise ValueError(
                f"input_reference must be 'zero' or 'steady_state', got {self.input_reference!r}"
            )
        for name in ("observer_gain", "margin_forgetting"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name} must lie in (0, 1], got {getattr(self, name)}")
        if not 0 <= self.offset_gain <= 1:
            raise ValueError(f"offset_gain must lie in [0, 1], got {self.offset_gain}")
        for name in (
            "observer_limit",
            "observer_input_gain",
            "observer_input_limit",
            "margin_gain",
            "margin_limit",
            "margin_initial",
            "goal_integral_gain",
            "goal_integral_radius",
            "goal_integral_limit",
            "goal_integral_angle_limit",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.input_step is not None and not self.input_step > 0:
            raise ValueError(f"input_step must be > 0 or None, got {self.input_step}")
        if not self.offset_limit >= 0:
            raise ValueError(f"offset_limit must be >= 0, got {self.offset_limit}")
        if not 0 < self.backoff <= 1:
            raise ValueError(f"backoff must lie in (0, 1], got {self.backoff}")
        # tighten only: a looser bound than the environment's would plan into violations
        fractions = (
            *self.vehicle_speed_fraction,
            self.joint_speed_fraction,
            self.joint_position_fraction,
        )
        if len(self.vehicle_speed_fraction) != 2 or not all(0 < f <= 1 for f in fractions):
            raise ValueError(
                "vehicle_speed_fraction (2), joint_speed_fraction and joint_position_fraction "
                f"must lie in (0, 1], got {self.vehicle_speed_fraction}, "
                f"{self.joint_speed_fraction}, {self.joint_position_fraction}"
            )
        penalty = self.joint_position_penalty
        if penalty is not None and (
            len(penalty) != 2 or not penalty[0] >= 0 or not 0 < penalty[1] < np.inf
        ):
            raise ValueError(
                "joint_position_penalty must be None or (L1 >= 0, L2 > 0) (the soft rows need "
                f"a quadratic penalty), got {penalty}"
            )
        if not self.pitch_margin_extra >= 0:
            raise ValueError(f"pitch_margin_extra must be >= 0, got {self.pitch_margin_extra}")
        if not self.manipulability_factor >= 1:
            raise ValueError(
                f"manipulability_factor must be >= 1, got {self.manipulability_factor}"
            )
        if not 0 < self.pitch_margin < np.pi / 2:
            raise ValueError(f"pitch_margin must lie in (0, pi/2), got {self.pitch_margin}")

    @classmethod
    def paper(cls, **changes: object) -> NMPCSettings:
        """The paper's controller (no disturbance observer), with ``changes``."""
        return cls(**{"disturbance_observer": False, "input_step": None, **changes})  # type: ignore[arg-type]

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


CONTROLLERS = ("observer", "paper")


def controller_settings(controller: str, **changes: object) -> NMPCSettings:
    """The settings of a named controller: ``observer`` (the default settings: offset-free
    prediction with the disturbance observer) or ``paper`` (``NMPCSettings.paper``)."""
    if controller not in CONTROLLERS:
        raise ValueError(f"controller must be one of {CONTROLLERS}, got {controller!r}")
    if controller == "paper":
        return NMPCSettings.paper(**changes)
    return NMPCSettings(**changes)  # type: ignore[arg-type]
