"""The object's shape as parameters: its functions read every number that tells one object
from another from p_O, so objects of one strip capacity share their code (one compiled
library), and give what the shape as constants of the code gave.

The reference is written here from the hydrodynamics module's functions with the object's
numbers as constants (how ``ObjectModel`` built its functions before the shape became a
parameter), not from the parametric code under test.
"""

from __future__ import annotations

import casadi as cs
import numpy as np
import pytest

from uvms_env.dynamics import ObjectModel
from uvms_env.dynamics.hydro import current_twist_rate, kirchhoff_coriolis, strip_damping
from uvms_env.dynamics.payload import (
    NPO,
    OBJECT_PARAMETER_LAYOUT,
    STRIP_SIZE,
    parameter_layout,
    strip_capacity,
)
from uvms_env.dynamics.spatial import rot_zyx
from uvms_env.models import load_parameters
from uvms_env.scenarios import make
from uvms_env.sim.simulator import Simulator, compiled_chain, draw_truth_parameters

OBJECTS = [("bar", 0.0), ("ring", 1.6), ("ring", 0.9), ("bar", 5.0), ("bar", 8.2)]


def _baked_dynamics(obj: ObjectModel) -> cs.Function:
    """(x_O, v_O, v_c, p_O physical) -> (M_O, h_O) with the shape as constants."""
    prm = load_parameters()
    rho, g = prm.water_density, prm.gravity
    x, v = cs.SX.sym("x_O", 6), cs.SX.sym("v_O", 6)
    v_c, p = cs.SX.sym("v_c", 3), cs.SX.sym("p", NPO)
    mass = p[OBJECT_PARAMETER_LAYOUT["mass"]]
    m_rb = mass * cs.DM(obj.unit_inertia)
    m_a = p[OBJECT_PARAMETER_LAYOUT["added_mass_scale"]] * cs.DM(obj.added_mass)
    rot = rot_zyx(x[3:6])
    rb = cs.diagcat(rot.T, rot.T)
    body = rb @ v
    vc_body = rot.T @ v_c
    v_r = body - cs.vertcat(vc_body, cs.DM.zeros(3))
    m_tot = m_rb + m_a
    frame_rate = cs.vertcat(-cs.cross(body[3:], body[:3]), cs.DM.zeros(3))
    h_body = (
        m_tot @ frame_rate
        - m_a @ current_twist_rate(body[3:], vc_body)
        + kirchhoff_coriolis(m_rb, body)
        + kirchhoff_coriolis(m_a, v_r)
        + strip_damping(v_r, obj.strips, obj.coef, p[OBJECT_PARAMETER_LAYOUT["drag_scale"]])
    )
    net = (mass - rho * p[OBJECT_PARAMETER_LAYOUT["displaced_volume"]]) * g
    m_w = rb.T @ m_tot @ rb
    return cs.Function(
        "baked",
        [x, v, v_c, p],
        [0.5 * (m_w + m_w.T), rb.T @ h_body + cs.vertcat(0, 0, -net, 0, 0, 0)],
    )


@pytest.mark.parametrize(("shape", "size"), OBJECTS)
def test_the_parametric_object_is_the_object_with_its_shape_as_constants(shape, size, rng):
    """Mass matrix and bias (drag, added mass, Kirchhoff terms, net weight) from p_O agree
    with the shape as constants, at random poses, twists and currents and perturbed
    physical parameters; so does the Jacobian of the bias over the twist (what the
    controller's sensitivities differentiate)."""
    obj = ObjectModel(shape, size)
    baked = _baked_dynamics(obj)
    x, v = cs.SX.sym("x", 6), cs.SX.sym("v", 6)
    p = obj.nominal_parameters()
    jac_new = cs.Function("jn", [x, v], [cs.jacobian(obj.dynamics(x, v, 0, p)[1], v)])
    jac_old = cs.Function("jo", [x, v], [cs.jacobian(baked(x, v, 0, p[:NPO])[1], v)])
    for _ in range(5):
        pose = np.r_[rng.uniform(-3, 3, 3), rng.uniform(-1.2, 1.2, 3)]
        twist, current = rng.uniform(-0.5, 0.5, 6), rng.uniform(-0.3, 0.3, 3)
        p[:NPO] = obj.nominal_parameters()[:NPO] * rng.uniform(0.8, 1.2, NPO)
        for new, old in zip(
            obj.dynamics(pose, twist, current, p), baked(pose, twist, current, p[:NPO]), strict=True
        ):
            old = np.array(old)
            np.testing.assert_allclose(np.array(new), old, rtol=0, atol=1e-12 * np.abs(old).max())
        old = np.array(jac_old(pose, twist))
        np.testing.assert_allclose(
            np.array(jac_new(pose, twist)), old, rtol=0, atol=1e-12 * np.abs(old).max()
        )


def test_one_capacity_one_code_and_the_capacities():
    """Every ring and the bars of up to 24 strips (5.4 m) build the same functions (one
    compiled library); longer bars the next capacity. The padding strips have length 0."""
    sources = set()
    for shape, size in [("bar", 0.0), ("ring", 1.6), ("ring", 0.9), ("bar", 5.0)]:
        obj = ObjectModel(shape, size)
        assert obj.capacity == 24
        sources.add(str(obj.dynamics.serialize()))
        strips = obj.nominal_parameters()[parameter_layout(24)["strips"]].reshape(24, STRIP_SIZE)
        count = len(obj.strips.lengths)
        np.testing.assert_array_equal(strips[count:, 6], 0.0)
        np.testing.assert_allclose(strips[:count, 6], obj.strips.lengths)
    assert len(sources) == 1
    assert ObjectModel("bar", 6.6).capacity == ObjectModel("bar", 8.2).capacity == 48
    assert strip_capacity(1) == strip_capacity(24) == 24 and strip_capacity(25) == 48


def test_the_mismatch_draw_perturbs_the_physics_not_the_shape():
    """The truth draw perturbs the four physical parameters only: the object's shape is
    what the scenario says, at every mismatch."""
    s = make("paper")
    sim = Simulator(s)
    nominal = sim.nominal_object_parameters
    _, po = draw_truth_parameters(s, sim.nominal_parameters, nominal, np.random.default_rng(3), 0.2)
    assert not np.allclose(po[:NPO], nominal[:NPO])
    np.testing.assert_array_equal(po[NPO:], nominal[NPO:])


def test_a_ring_and_the_bar_share_the_chain_and_differ_by_their_parameters():
    """The closed chain of two robots is one compiled function for the paper's bar and a
    ring (same capacity); what the object is comes from P_O: the same state and inputs
    move the bar and the ring differently."""
    paper = make("paper")
    timing = (paper.period, paper.substeps)  # the simulator's own chain: nothing compiled here
    bar, ring = (
        compiled_chain(2, shape, size, *timing) for shape, size in [("bar", 0.0), ("ring", 1.6)]
    )
    assert bar[1] is ring[1]
    sim = Simulator(paper)
    assert sim._compiled_step().fn is bar[1]
    x, tau, vc, p, po = (np.array(a, dtype=float) for a in sim.wrench_inputs())
    tau[:] = 0.3 * sim.tau_max
    args = (x, tau.T, vc, p.T)
    grasp = sim._grasp.T
    step_bar = np.array(bar[1](*args, po, grasp, paper.period)[0]).ravel()
    po_ring = ObjectModel("ring", 1.6).nominal_parameters()
    step_ring = np.array(ring[1](*args, po_ring, grasp, paper.period)[0]).ravel()
    assert np.all(np.isfinite(step_bar)) and np.all(np.isfinite(step_ring))
    assert np.max(np.abs(step_bar - step_ring)) > 1e-6


def _ring_grasps(radius: float, angles_deg: list[float]) -> list[np.ndarray]:
    a = np.radians(angles_deg)
    return [np.array([radius * np.cos(t), radius * np.sin(t), 0.0]) for t in a]


# objects cut exactly by their grasps: each share's piece is whole strips around the grasp
TILINGS = [
    (("bar", 0.0), [np.array([0.0, y, 0.0]) for y in (-0.8, 0.8)], [0.5, 0.5]),
    (("bar", 3.6), [np.array([0.0, y, 0.0]) for y in (-1.35, -0.45, 0.45, 1.35)], [0.25] * 4),
    (("bar", 3.6), [np.array([0.0, y, 0.0]) for y in (-1.6, 0.45)], [0.25, 0.75]),
    (("ring", 1.6), _ring_grasps(1.6, [45, 135, 225, 315]), [0.25] * 4),
]


@pytest.mark.parametrize(("obj", "grasps", "shares"), TILINGS)
def test_pieces_that_tile_the_object_add_up_to_its_dynamics(obj, grasps, shares, rng):
    """The object's (M_O, h_O) are linear in its strips, mass and volume: pieces that cut it
    into disjoint parts sum to the whole at any pose, twist and current."""
    o = ObjectModel(*obj)
    pieces = [o.carried_parameters(g, c) for g, c in zip(grasps, shares, strict=True)]
    for _ in range(3):
        x = np.concatenate([rng.normal(size=3), rng.uniform(-0.6, 0.6, 3)])
        v, v_c = 0.3 * rng.normal(size=6), 0.2 * rng.normal(size=3)
        whole = [np.array(t) for t in o.dynamics(x, v, v_c, o.nominal_parameters())]
        parts = [[np.array(t) for t in o.dynamics(x, v, v_c, p)] for p in pieces]
        for k in range(2):
            np.testing.assert_allclose(sum(p[k] for p in parts), whole[k], rtol=1e-12, atol=1e-12)


def test_a_piece_lies_around_its_grasp_and_a_whole_share_is_the_object():
    o = ObjectModel("bar", 8.2)
    layout, mass = parameter_layout(o.capacity), OBJECT_PARAMETER_LAYOUT["mass"]
    np.testing.assert_array_equal(
        o.carried_parameters(np.array([0.0, 3.9, 0.0]), 1.0), o.nominal_parameters()
    )
    for y, share in ((3.9, 0.1), (0.0, 0.2), (-2.0, 0.3)):
        p = o.carried_parameters(np.array([0.0, y, 0.0]), share)
        assert p[mass] == pytest.approx(share * o.nominal_mass)
        strips = p[layout["strips"]].reshape(o.capacity, STRIP_SIZE)
        centers = strips[strips[:, 6] > 0, 1]
        # the strips nearest the grasp, scaled to the share's length, shifted inwards at the end
        held = strips[:, 6].sum()
        assert share * o.length <= held < share * o.length + 0.226
        lo, hi = max(-o.length / 2, y - held), min(o.length / 2, y + held)
        assert lo <= centers.min() and centers.max() <= hi
        # the piece's centre of mass, from its first moment about the origin
        first = p[layout["unit_inertia"]].reshape(6, 6).T[3:, :3]
        assert abs(first[2, 0]) == pytest.approx(abs(np.mean(centers)), abs=1e-9)
    with pytest.raises(ValueError, match="share"):
        o.carried_parameters(np.zeros(3), 0.0)
    with pytest.raises(ValueError, match="piece"):
        o.carried_parameters(np.zeros(3), 0.5, 1.5)


@pytest.mark.parametrize(("shape", "size", "grasp"), [("bar", 8.2, 3.1), ("ring", 1.6, 0.0)])
def test_what_a_robot_carries_blends_its_share_of_the_whole_and_its_piece(shape, size, grasp, rng):
    """``piece`` 0: the share of the whole object's dynamics (the paper's model); between
    0 and 1, the blend of that and of the piece's, at any state."""
    o = ObjectModel(shape, size)
    g = np.array([0.0, grasp, 0.0]) if shape == "bar" else np.array([size, 0.0, 0.0])
    share = 0.3
    x = np.concatenate([rng.normal(size=3), rng.uniform(-0.6, 0.6, 3)])
    v, v_c = 0.3 * rng.normal(size=6), 0.2 * rng.normal(size=3)

    def dyn(p):
        return [np.array(t) for t in o.dynamics(x, v, v_c, p)]

    whole, piece = dyn(o.nominal_parameters()), dyn(o.carried_parameters(g, share, 1.0))
    for alpha in (0.0, 0.4):
        blend = dyn(o.carried_parameters(g, share, alpha))
        for k in range(2):
            expected = (1 - alpha) * share * whole[k] + alpha * piece[k]
            np.testing.assert_allclose(blend[k], expected, rtol=1e-12, atol=1e-12)
