"""Every per-step kinematic quantity of the whole team in ONE compiled CasADi call.

Per robot and per step: the object pose and twist estimated from the robot's own
(measured) kinematics, the nearest obstacles relative to that estimate, the
manipulability, the grasp error and the constraint values of the true state, a few
team-wide reductions of them, and the observation rows themselves, called through the
zero-copy ``BufferCall``. Each robot's waypoint sequencer runs inside too (on its own
estimate: it passes its waypoint within ``WAYPOINT_TOLERANCE``), and the navigation twist
towards its waypoint after that (``navigation.parametric``, the scene's parameters as an
input table): the observation comes out whole, and nothing of it is written twice. The
team's sequencer runs inside as well, on the true object, with the reward's potential
before and after it moves and the goal test (``team_sequenced``): the task's rules read
them from the team rows.

The scenario geometry enters as inputs, so a new random scenario with the same team size
reuses the compiled function. Padding and branch-free code (docs/batched.md, "One kernel
for every geometry"): an obstacle row with ``present == 0`` changes nothing (see
``_clearance_geometry``), nor does a repeated object segment; the kernel has no
``if_else``, so it also compiles for SIMD lanes or CUDA (``uvms_env.vector.kernels``).

May import: numpy, casadi, ``uvms_env.dynamics``, ``uvms_env.navigation`` (obstacle
types, the parametric twist, the tolerance), ``uvms_env.scenarios`` (types), ``uvms_env.sim``
and ``uvms_env.task`` (constraints, team_rows).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import TYPE_CHECKING, Any

import casadi as cs
import numpy as np

from uvms_env.dynamics import NQ, NU, UVMSModel
from uvms_env.dynamics.compiled import BufferCall, RebuiltOnUnpickle, compile_function
from uvms_env.dynamics.local_model import euler_zyx
from uvms_env.dynamics.spatial import rot_zyx, wrap_angle_sx
from uvms_env.dynamics.uvms import default_model
from uvms_env.navigation import Cylinder
from uvms_env.navigation.parametric import NAV_PARAMETERS, twist_of_row
from uvms_env.navigation.task_navigator import WAYPOINT_TOLERANCE, waypoint_table
from uvms_env.sim.chain import NG  # grasp per robot: offset l_i (3), R_Oi column-major (9)
from uvms_env.sim.simulator import compiled_chain, grasp_parameters
from uvms_env.task.constraints import (
    CONSTRAINTS,
    PAD_CYLINDER,
    PAD_SPHERE,
    SAFETY_CONSTRAINTS,
    ball_excess,
    capsule_clearance,
    constraint_scales,
    robot_constraints,
)
from uvms_env.task.team_rows import TEAM_INPUT

if TYPE_CHECKING:
    from uvms_env.scenarios import Scenario


#: Obstacle slots of every kernel, single and batched (absent rows are far-away stand-ins,
#: see PAD_* in constraints): the random family draws at most five obstacles of a kind, the
#: paper scenario has three cylinders, so one compiled kernel serves every scenario of a
#: team size, object and sensing; a scenario with more obstacles of a kind uses its count.
#: The price of the empty rows, per kernel call (2-core EPYC without AVX-512, 2026-12-07,
#: fastest of 61 repeats): the paper 13.3 -> 14.2 us, a random N = 4 scene with 2 + 1
#: obstacles 26.6 -> 33.4 us, of an environment step of 0.3-1 ms; a kernel per padded
#: count (0, 2 or 5 of each kind) cost a user up to nine compiles per team size.
CYLINDER_SLOTS = 5
SPHERE_SLOTS = 5
NS = 13  # per robot, known a priori: load share, grasp offset, R_Oi row-major
#: Waypoint slots of a kernel: the random family draws at most three, the paper has three;
#: a scenario with more uses its own count.
WAYPOINT_SLOTS = 3
#: Rows of the per-robot ``scalars`` output: manipulability, grasp error, own clearance,
#: violated safety constraints (its ``cost``), squared clipped action.
ROBOT_SCALARS = 5
ROBOT_VIOLATED = 3
Layout = tuple[tuple[str, int], ...]  # the observation's (name, size) blocks, in order


def _nearest(
    features: list[cs.SX], dist: list[cs.SX], valid: list[cs.SX], count: int, far: cs.DM
) -> cs.SX:
    """The ``count`` valid features of smallest distance, nearest first (ties by index);
    a slot left without one holds ``far``. Rank counting: a feature's rank is the number
    of valid ones nearer, O(M^2) comparisons, cheap in C; padding rows count nowhere,
    wherever they are.

    Branch-free: slot ``s`` adds ``[rank_j == s] * valid_j * (feature_j - far)`` over the
    obstacles, exactly the feature's offset or zero (features are finite, padding rows
    too; ``valid`` is 0 or 1)."""
    m = len(features)
    rank = [
        sum(
            (
                valid[k] * ((dist[k] < dist[j]) if k > j else (dist[k] <= dist[j]))
                for k in range(m)
                if k != j
            ),
            cs.SX(0.0),
        )
        for j in range(m)
    ]
    slots = []
    for s in range(count):
        slot = cs.SX(far)  # stays far unless a real obstacle has rank s
        for j in range(m):
            slot += ((rank[j] == s) * valid[j]) * (features[j] - far)
        slots.append(slot)
    return cs.vertcat(*slots)


def _clearance_geometry(cyl: cs.SX, sph: cs.SX) -> tuple[cs.SX, cs.SX]:
    """The obstacles as ``capsule_clearance`` takes them (cylinders 3 x C, spheres 4 x P)
    with the radius of an absent obstacle (``present == 0``) replaced by -inf, so that its
    clearance is +inf and never the min. Branch-free and exact: ``fmin(r, +inf) == r``,
    ``fmin(r, -inf) == -inf`` (``(2 present - 1) inf`` is +-inf, never NaN)."""

    def radius(r: cs.SX, present: cs.SX) -> cs.SX:
        return cs.fmin(r, (2.0 * present - 1.0) * np.inf)

    return (
        cs.vertcat(cyl[:2, :], radius(cyl[2, :], cyl[3, :])),
        cs.vertcat(sph[:3, :], radius(sph[3, :], sph[4, :])),
    )


def _obstacle_features(pose: cs.SX, cyl: cs.SX, sph: cs.SX) -> tuple[list, list, list]:
    """Per obstacle slot: its observed features (dx dy dz radius is_cylinder from the own
    object estimate ``pose``), its surface distance and its validity flag."""
    feats, dists, valid = [], [], []
    for k in range(cyl.shape[1]):
        c = cyl[:, k]
        dx, dy = c[0] - pose[0], c[1] - pose[1]
        feats.append(cs.vertcat(dx, dy, 0.0, c[2], 1.0))
        dists.append(cs.sqrt(dx * dx + dy * dy + 1e-18) - c[2])
        valid.append(c[3])
    for k in range(sph.shape[1]):
        sp = sph[:, k]
        d = sp[:3] - pose[:3]
        feats.append(cs.vertcat(d, sp[3], 0.0))
        dists.append(cs.sqrt(cs.dot(d, d) + 1e-18) - sp[3])
        valid.append(sp[4])
    return feats, dists, valid


def _body_clearance(
    uvms: UVMSModel, q: cs.SX, cyl: cs.SX, sph: cs.SX, ws: cs.SX
) -> tuple[cs.SX, cs.SX]:
    """The robot's physical bodies at ``q`` (vehicle ball, arm capsules): their smallest
    clearance to the obstacles and their largest excess beyond the workspace."""
    prm = uvms.params
    pts = uvms.body_points(q)
    r_veh, r_tube = prm.vehicle.bounding_radius, prm.arm.tube_radius
    cyl_g, sph_g = _clearance_geometry(cyl, sph)
    own = capsule_clearance(pts[:, 0], pts[:, 0], r_veh, cyl_g, sph_g)
    for k in range(1, pts.shape[1] - 1):
        own = cs.fmin(own, capsule_clearance(pts[:, k], pts[:, k + 1], r_tube, cyl_g, sph_g))
    excess = ball_excess(
        [(pts[:, 0], r_veh)] + [(pts[:, k], r_tube) for k in range(1, pts.shape[1])], ws
    )
    return own, excess


def _row(table: cs.SX, i: cs.SX) -> cs.SX:
    """Column ``i`` of a waypoint ``table``, branch-free (a sum of one-hot columns)."""
    return sum((cs.SX(float(w)) == i) * table[:, w] for w in range(table.shape[1]))


def _advanced(index: cs.SX, done: cs.SX, near: cs.SX, count: cs.SX) -> tuple:
    """A sequencer at ``index`` (``done``: past its last waypoint) that is ``near`` its
    waypoint moves to the next (at the last one: done). Returns the new index and done
    flag, and whether an intermediate waypoint was passed."""
    near = (1.0 - done) * near
    last = index + 1.0 >= count
    passed = near * (1.0 - last)
    return index + passed, done + near * last, passed


def _sequenced(pose: cs.SX, sequencer: cs.SX, table: cs.SX, count: cs.SX) -> tuple:
    """One robot's waypoint sequencer on its estimate ``pose``: ``sequencer`` = [index,
    done] (floats), the scene's waypoints as ``table`` (NAV_PARAMETERS, W) rows of
    ``parameter_row``, ``count`` of them real. It passes its waypoint within the tolerance
    (the last one: done). Returns the new [index, done], its waypoint (6,) and the
    navigation twist towards it, branch-free."""
    index, done = sequencer[0], sequencer[1]
    d = pose[:3] - _row(table, index)[:3]
    index, done, _ = _advanced(index, done, cs.dot(d, d) < WAYPOINT_TOLERANCE**2, count)
    new = _row(table, index)
    return cs.vertcat(index, done), new[:6], twist_of_row(pose, new)


def _potential(x_o: cs.SX, target: cs.SX, attitude: cs.SX) -> tuple[cs.SX, cs.SX]:
    """The reward's potential of the true object ``x_o`` towards ``target`` (6,),
    Phi = |p_O - p_wp| + w_attitude |wrap(Theta_O - Theta_wp)|, and its distance term."""
    d = x_o - target
    att = wrap_angle_sx(d[3:])
    dist = cs.sqrt(cs.dot(d[:3], d[:3]))
    return dist + attitude * cs.sqrt(cs.dot(att, att)), dist


def team_sequenced(x_o: cs.SX, team: cs.SX, table: cs.SX, count: cs.SX, goal: cs.SX) -> cs.SX:
    """The team's waypoint sequencer on the true object ``x_o``, and the task's tests of
    it: ``team`` = [index, done, attitude weight, position tolerance, attitude tolerance]
    (``TEAM_INPUT``), ``table``/``count`` as ``_sequenced`` takes them. Returns the rows
    ``TEAM_SEQUENCER`` (new index, done), ``POTENTIAL`` (towards the waypoint before the
    sequencer moves), ``POTENTIAL_AFTER`` (towards the one after), ``PASSED`` (an
    intermediate waypoint) and ``AT_GOAL`` (within both tolerances of ``goal``) of
    ``uvms_env.task.team_rows``."""
    index, done, attitude, pos_tol, att_tol = (team[i] for i in range(TEAM_INPUT))
    before, dist = _potential(x_o, _row(table, index)[:6], attitude)
    index, done, passed = _advanced(index, done, dist < WAYPOINT_TOLERANCE, count)
    after, _ = _potential(x_o, _row(table, index)[:6], attitude)
    d_goal = x_o - goal
    at_goal = (cs.sqrt(cs.dot(d_goal[:3], d_goal[:3])) < pos_tol) * (
        cs.mmax(cs.fabs(wrap_angle_sx(d_goal[3:]))) < att_tol
    )
    return cs.vertcat(index, done, before, after, passed, at_goal)


def _team_sequencer_function(w_slots: int) -> cs.Function:
    """``team_sequenced`` as an SX function (called inside the MX kernel)."""
    x_o, team = cs.SX.sym("x_O", 6), cs.SX.sym("team", TEAM_INPUT)
    table, count = cs.SX.sym("waypoints", NAV_PARAMETERS, w_slots), cs.SX.sym("count")
    goal = cs.SX.sym("goal", 6)
    out = team_sequenced(x_o, team, table, count, goal)
    return cs.Function("env_team", [x_o, team, table, count, goal], [out], {"cse": True})


def robot_function(
    uvms: UVMSModel,
    n_cyl: int,
    n_sph: int,
    layout: Layout,
    far: Sequence[float],
    noisy: bool,
    w_slots: int = WAYPOINT_SLOTS,
) -> cs.Function:
    """Per-robot part of the kernel (SX; mapped over the team). Without noise the
    measurements are the true state: the measured inputs are ignored, so the estimate
    and the true-state terms share their subexpressions."""
    prm = uvms.params
    a, q, zeta = cs.SX.sym("a", NU), cs.SX.sym("q", NQ), cs.SX.sym("zeta", NQ)
    qm, zm = cs.SX.sym("q_meas", NQ), cs.SX.sym("zeta_meas", NQ)
    x_o, grasp = cs.SX.sym("x_O", 6), cs.SX.sym("grasp", NG)
    static = cs.SX.sym("static", NS)
    seq = cs.SX.sym("sequencer", 2)
    table, count = cs.SX.sym("waypoints", NAV_PARAMETERS, w_slots), cs.SX.sym("count")
    goal, tf = cs.SX.sym("goal", 6), cs.SX.sym("time_fraction")
    cyl, sph = cs.SX.sym("cylinders", 4, n_cyl), cs.SX.sym("spheres", 5, n_sph)
    ws, obj = cs.SX.sym("workspace", 4), cs.SX.sym("object_terms", 2)
    offset, r_oi = grasp[:3], cs.reshape(grasp[3:], 3, 3)
    q_est, z_est = (qm, zm) if noisy else (q, zeta)

    # Own estimate of the object from measured kinematics and the known grasp.
    p_ee, r_ee = uvms.ee_pose(q_est)
    r_o = r_ee @ r_oi.T
    arm = r_o @ offset
    pose = cs.vertcat(p_ee - arm, euler_zyx(r_o))
    v_ee = uvms.ee_jacobian(q_est) @ z_est
    twist = cs.vertcat(v_ee[:3] + cs.cross(arm, v_ee[3:]), v_ee[3:])
    observed = dict(layout)["obstacles"] // len(far)
    seq_next, wp, nav = _sequenced(pose, seq, table, count)
    blocks = {
        "q": q_est,
        "zeta": z_est,
        "object_pose": pose,
        "object_twist": twist,
        "waypoint": wp,
        "nav_velocity": nav,
        "goal": goal,
        "obstacles": _nearest(*_obstacle_features(pose, cyl, sph), observed, cs.DM(list(far))),
        "load_share": static[0],
        "grasp_offset": static[1:4],
        "grasp_rotation": static[4:13],
        "time_fraction": tf,
    }
    for name, size in layout:
        if name in blocks and blocks[name].numel() != size:
            raise ValueError(
                f"observation block {name!r} has {blocks[name].numel()} entries, "
                f"the layout says {size}"
            )
    obs = cs.vertcat(*[blocks.get(name, cs.SX.zeros(size)) for name, size in layout])

    # The true state: physical bodies, grasp error, constraints.
    manip = uvms.manipulability(q)
    own, excess = _body_clearance(uvms, q, cyl, sph, ws)
    p_ee_t, _ = uvms.ee_pose(q)
    e = p_ee_t - (x_o[:3] + rot_zyx(x_o[3:]) @ offset)
    g = robot_constraints(
        prm, a, q, zeta, x_o[4], manip, cs.fmin(own, obj[0]), cs.fmax(excess, obj[1])
    )
    a_clip = cs.fmin(cs.fmax(a, -1.0), 1.0)
    scalars = cs.vertcat(
        manip,
        cs.sqrt(cs.dot(e, e)),
        own,
        cs.sum1(g[_SAFETY_ROWS] > 0.0),
        cs.dot(a_clip, a_clip),
    )
    return cs.Function(
        "env_robot",
        [a, q, zeta, qm, zm, x_o, grasp, static, seq, table, count, goal, tf, cyl, sph, ws, obj],
        [obs, pose, g, scalars, seq_next],
        {"cse": True},
    )


_SAFETY_ROWS = [CONSTRAINTS.index(c) for c in SAFETY_CONSTRAINTS]


def _graded(g: cs.MX, n: int) -> cs.MX:
    """The team rows ``EXCESS``, ``MAX_EXCESS``, ``VIOLATED_ROBOTS`` and ``ANY_VIOLATED`` of
    the robots' constraint values ``g`` (8, n) (``uvms_env.task.team_rows``)."""
    inv = cs.DM([1.0 / s for s in constraint_scales(default_model().params)])
    excess = cs.fmax(g, 0.0) * cs.repmat(inv, 1, n)
    largest = cs.vertcat(*[cs.mmax(excess[k, :]) for k in range(len(CONSTRAINTS))])
    violated = g > 0.0
    any_safety = cs.sum2(cs.sum1(violated[_SAFETY_ROWS, :]) > 0.0)
    return cs.vertcat(cs.sum2(excess), largest, cs.sum2(violated), any_safety)


def object_function(radius: float, n_seg: int, n_cyl: int, n_sph: int) -> cs.Function:
    """Clearance and workspace excess of the object (capsules along its segments)."""
    x_o, seg = cs.SX.sym("x_O", 6), cs.SX.sym("segments", 6, n_seg)
    cyl, sph = cs.SX.sym("cylinders", 4, n_cyl), cs.SX.sym("spheres", 5, n_sph)
    ws = cs.SX.sym("workspace", 4)
    rot = rot_zyx(x_o[3:])
    cyl_g, sph_g = _clearance_geometry(cyl, sph)
    clearance, balls = cs.SX(np.inf), []
    for k in range(n_seg):
        a = x_o[:3] + rot @ seg[:3, k]
        b = x_o[:3] + rot @ seg[3:, k]
        clearance = cs.fmin(clearance, capsule_clearance(a, b, radius, cyl_g, sph_g))
        balls += [(a, radius), (b, radius)]
    return cs.Function(
        "env_object",
        [x_o, seg, cyl, sph, ws],
        [cs.vertcat(clearance, ball_excess(balls, ws))],
        {"cse": True},
    )


@cache
def team_function(
    n: int,
    n_seg: int,
    n_cyl: int,
    n_sph: int,
    layout: Layout,
    far: tuple[float, ...],
    noisy: bool,
    w_slots: int = WAYPOINT_SLOTS,
    wrench: cs.Function | None = None,
) -> cs.Function:
    """The symbolic kernel for n robots (MX around the per-robot SX function, mapped;
    branch-free, see the module doc): what ``team_kernel`` compiles, and what a batched
    build (``uvms_env.vector.kernels``) generates its code from.

    Inputs, in order (CasADi shapes; ``TeamKinematics.__call__`` passes each as the
    C-contiguous transpose): a (8, n), q, zeta, q_meas, zeta_meas (10, n), x_O (6,),
    grasp (12, n), static (13, n), sequencers (2, n) (each robot's waypoint index and
    done flag, as floats), team (5,) (the team's sequencer and its constants,
    ``TEAM_INPUT``), waypoints (NAV_PARAMETERS, w_slots) (``parameter_row`` of each,
    zeros beyond the count), count (1,), goal (6,), time_fraction (1,), segments
    (6, n_seg), cylinders (4, n_cyl), spheres (5, n_sph), workspace (4,).
    Outputs: observation (size, n), pose (6, n), constraints (8, n), scalars (5, n),
    team (``TEAM_ROWS``,), sequencers (2, n) after this evaluation.

    With ``wrench`` (the closed chain's ``internal_wrench``, inputs x, tau, v_c, P, P_O,
    grasp): its inputs but the grasp come after those, and one more output, the squeeze's
    squared norm (1,): the metric's sample, in the same call as everything else the task
    reads after the period."""
    uvms = default_model()
    robot = robot_function(uvms, n_cyl, n_sph, layout, far, noisy, w_slots).map(n, "serial")
    obj = object_function(uvms.params.object.tube_radius, n_seg, n_cyl, n_sph)
    a, q, zeta = cs.MX.sym("a", NU, n), cs.MX.sym("q", NQ, n), cs.MX.sym("zeta", NQ, n)
    qm, zm = cs.MX.sym("q_meas", NQ, n), cs.MX.sym("zeta_meas", NQ, n)
    x_o, grasp = cs.MX.sym("x_O", 6), cs.MX.sym("grasp", NG, n)
    static, seq = cs.MX.sym("static", NS, n), cs.MX.sym("sequencers", 2, n)
    team_in = cs.MX.sym("team", TEAM_INPUT)
    table, count = cs.MX.sym("waypoints", NAV_PARAMETERS, w_slots), cs.MX.sym("count")
    goal, tf = cs.MX.sym("goal", 6), cs.MX.sym("time_fraction")
    seg = cs.MX.sym("segments", 6, n_seg)
    cyl, sph = cs.MX.sym("cylinders", 4, n_cyl), cs.MX.sym("spheres", 5, n_sph)
    ws = cs.MX.sym("workspace", 4)
    obj_terms = obj(x_o, seg, cyl, sph, ws)
    obs, pose, g, scalars, seq_next = robot(
        a, q, zeta, qm, zm, x_o, grasp, static, seq, table, count, goal, tf, cyl, sph, ws,
        obj_terms,
    )  # fmt: skip
    team = cs.vertcat(
        cs.fmin(cs.mmin(scalars[2, :]), obj_terms[0]),  # clearance of every body
        cs.mmin(scalars[0, :]),  # manipulability
        cs.mmax(scalars[1, :]),  # grasp error
        cs.sum2(scalars[3, :]),  # violated safety constraints, all robots
        cs.sum2(scalars[4, :]),  # sum of squared clipped normalized actions
        cs.sum2(g > 0.0) > 0.0,  # per kind: violated by any robot
        obj_terms,
        _team_sequencer_function(w_slots)(x_o, team_in, table, count, goal),
        _graded(g, n),
    )
    inputs = [a, q, zeta, qm, zm, x_o, grasp, static, seq, team_in, table, count, goal, tf]
    inputs += [seg, cyl, sph, ws]
    outputs = [obs, pose, g, scalars, team, seq_next]
    name = f"env_kernel_n{n}_s{n_seg}_c{n_cyl}_p{n_sph}_w{w_slots}{'_noisy' if noisy else ''}"
    if wrench is not None:
        chain_args = [cs.MX.sym(wrench.name_in(i), wrench.sparsity_in(i)) for i in range(5)]
        outputs.append(cs.sumsqr(wrench(*chain_args, grasp)))
        inputs += chain_args
        name += f"_{wrench.name()}"
    return cs.Function(name, inputs, outputs)


@cache
def team_kernel(*args: Any, chain: tuple | None = None) -> cs.Function:
    """``team_function(*args)`` compiled (once per process and size; the library is
    cached on disk): the kernel the single environment calls. ``chain``: the simulator's
    chain (object shape, size, period, substeps) whose internal wrench it also samples."""
    wrench = None if chain is None else compiled_chain(args[0], *chain)[0].internal_wrench
    return compile_function(team_function(*args, wrench=wrench))


def obstacle_inputs(scenario: Scenario, n_cyl: int, n_sph: int) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's ``cylinders`` (n_cyl, 4) rows ``[x, y, r, present]`` and ``spheres``
    (n_sph, 5) rows ``[cx, cy, cz, r, present]`` of a scenario, padded with absent rows
    (far-away stand-ins, ``present = 0``). Raises ValueError if it has more obstacles of
    a kind than slots."""
    cyl = [o for o in scenario.obstacles if isinstance(o, Cylinder)]
    sph = [o for o in scenario.obstacles if not isinstance(o, Cylinder)]
    if len(cyl) > n_cyl or len(sph) > n_sph:
        raise ValueError(
            f"the scenario has {len(cyl)} cylinders and {len(sph)} spheres; the kernel has "
            f"slots for {n_cyl} and {n_sph}"
        )
    cylinders = np.array([(*PAD_CYLINDER, 0.0)] * n_cyl).reshape(n_cyl, 4)
    for k, c in enumerate(cyl):
        cylinders[k] = (c.x, c.y, c.radius, 1.0)
    spheres = np.array([(*PAD_SPHERE, 0.0)] * n_sph).reshape(n_sph, 5)
    for k, sp in enumerate(sph):
        spheres[k] = (*sp.center, sp.radius, 1.0)
    return cylinders, spheres


def segment_inputs(segments: Sequence[tuple[np.ndarray, np.ndarray]], n_seg: int) -> np.ndarray:
    """The kernel's ``segments`` (n_seg, 6) rows ``[a, b]``, the last segment repeated up
    to ``n_seg`` (neutral: the object terms are a min and a max over segments)."""
    if not 1 <= len(segments) <= n_seg:
        raise ValueError(f"{len(segments)} segments do not fit {n_seg} slots (at least one)")
    rows = [np.concatenate([a, b]) for a, b in segments]
    return np.ascontiguousarray(rows + [rows[-1]] * (n_seg - len(rows)), dtype=float)


class TeamKinematics(RebuiltOnUnpickle):
    """Evaluates the kernel for one scenario; outputs are views overwritten by each call.

    ``layout`` is the observation's (name, size) list: the kernel fills every block it
    knows (q, zeta, object_pose, object_twist, waypoint, nav_velocity, goal, obstacles,
    load_share, grasp_offset, grasp_rotation, time_fraction) and leaves zeros in the
    others. Input set by the owner: ``time_fraction`` (1,); ``__call__`` takes the robots'
    sequencers.

    After ``__call__``, per robot (rows): ``observation`` (N, size), ``pose_estimate``
    (N, 6), ``constraints`` (N, 8) in the order of ``CONSTRAINTS``, ``manipulability``,
    ``grasp_error`` (m), ``clearance`` of the robot's own bodies (m), ``violated_count``,
    ``sequencers`` (N, 2) after this evaluation. Team: ``team_rows()`` (with the team's
    sequencer after this evaluation, which the task commits or not). With ``chain``
    (the simulator's ``chain_key``), ``__call__`` also takes the simulator's
    ``wrench_inputs()`` and ``wrench_sq`` (1,) holds the internal wrench's squared norm.
    """

    _rebuilt = ("_call",)

    def __init__(
        self,
        scenario: Scenario,
        segments: Sequence[tuple[np.ndarray, np.ndarray]],
        layout: Layout,
        far: Sequence[float],
        slots: tuple[int, int] | None = None,
        chain: tuple | None = None,
    ) -> None:
        """``slots``: (cylinders, spheres) of the kernel; default: ``CYLINDER_SLOTS`` and
        ``SPHERE_SLOTS``, or the scenario's count where larger (the results are the same
        with any padding)."""
        self._init_args = (scenario, segments, layout, far, slots, chain)
        self.n = n = scenario.n_agents
        if slots is None:
            cylinders = sum(isinstance(o, Cylinder) for o in scenario.obstacles)
            n_cyl = max(cylinders, CYLINDER_SLOTS)
            n_sph = max(len(scenario.obstacles) - cylinders, SPHERE_SLOTS)
        else:
            n_cyl, n_sph = slots
        self.cylinders, self.spheres = obstacle_inputs(scenario, n_cyl, n_sph)
        noisy = scenario.sensor_noise > 0
        s = scenario
        waypoints = waypoint_table(s.waypoints, s.workspace, s.obstacles, s.team_radius)
        w = max(len(waypoints), WAYPOINT_SLOTS)
        kernel = team_kernel(
            n, len(segments), n_cyl, n_sph, layout, tuple(far), noisy, w, chain=chain
        )
        self._call = BufferCall(kernel)
        self.segments = segment_inputs(segments, len(segments))
        self.workspace = np.array([*scenario.workspace.center, scenario.workspace.radius])
        self.grasp = grasp_parameters(scenario)
        self.static = np.ascontiguousarray(
            np.hstack(
                [
                    np.asarray(scenario.load_shares)[:, None],
                    scenario.grasp_offsets,
                    np.asarray(scenario.grasp_rotations).reshape(n, 9),  # row-major
                ]
            ),
            dtype=float,
        )
        self.waypoints = np.zeros((w, waypoints.shape[1]))
        self.waypoints[: len(waypoints)] = waypoints
        self.count = np.array([float(len(waypoints))])
        self.goal = np.array(scenario.waypoints[-1], dtype=float)
        self.time_fraction = np.zeros(1)
        out = self._call.outputs
        self.observation, self.pose_estimate, self.constraints = out[:3]
        scalars, self._team, self.sequencers = out[3], out[4].reshape(-1), out[5]
        self.manipulability, self.grasp_error = scalars[:, 0], scalars[:, 1]
        self.clearance, self.violated_count = scalars[:, 2], scalars[:, ROBOT_VIOLATED]
        self.wrench_sq = out[6].reshape(-1) if chain is not None else None

    def team_rows(self) -> np.ndarray:
        """The whole team output (T,) float64 (a view), the task's input: the rows of
        ``uvms_env.task.team_rows`` (min clearance of every body and the object, min
        manipulability, max grasp error, total violated, the squared clipped actions' sum,
        the kinds violated, the object's terms)."""
        return self._team

    def __call__(
        self,
        action: np.ndarray,
        q: np.ndarray,
        zeta: np.ndarray,
        q_meas: np.ndarray,
        zeta_meas: np.ndarray,
        x_o: np.ndarray,
        sequencers: np.ndarray,
        team: np.ndarray,
        *wrench_inputs: np.ndarray,
    ) -> None:
        """Evaluate on C-contiguous float64 arrays: action (N, 8) normalized as requested,
        true q, zeta (N, 10), measured q, zeta (N, 10), true object pose (6,), each robot's
        sequencer (N, 2): waypoint index and done flag, the team's sequencer and its
        constants (5,) (``TEAM_INPUT``); with a ``chain``, the simulator's
        ``wrench_inputs()``."""
        self._call(
            action,
            q,
            zeta,
            q_meas,
            zeta_meas,
            x_o,
            self.grasp,
            self.static,
            sequencers,
            team,
            self.waypoints,
            self.count,
            self.goal,
            self.time_fraction,
            self.segments,
            self.cylinders,
            self.spheres,
            self.workspace,
            *wrench_inputs,
        )
