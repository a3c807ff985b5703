"""Independent cross-check of the rigid-body terms of one UVMS against Pinocchio.

The project computes the rigid-body mass matrix and Coriolis/centrifugal terms with
adam-robotics; Pinocchio reads the same URDF and computes them with its own algorithms.
A change of conventions (base velocity representation, frame order, Euler angles)
in either shows up here.

Conventions mapped:

* configuration: the project's ``q = [x y z phi theta psi, q_1..q_4]`` (NED, ZYX Euler)
  becomes Pinocchio's free-flyer ``[x y z, quaternion (x y z w), q_1..q_4]`` with the
  quaternion of ``R = Rz(psi) Ry(theta) Rx(phi)``. Pinocchio's world frame is the NED
  frame (gravity is not taken from Pinocchio's model).
* velocity: Fossen's body-fixed twist ``[u v w p q r]`` is Pinocchio's LOCAL free-flyer
  velocity ``[v; omega]`` (the base origin's velocity and the angular velocity, both in
  body axes), so ``zeta`` is Pinocchio's ``v`` unchanged.
* the project adds a joint armature and hydrodynamic added mass to the mass matrix,
  drag, Kirchhoff terms, joint friction and the restoring force to the bias: the added
  mass and all hydrodynamics are switched off through the parameter vector ``p``, the
  armature is subtracted from the parameter file's value, and the restoring force
  ``h(q, 0)`` is compared on its own against a sum over bodies of weight and buoyancy.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uvms_env.dynamics.spatial import rot_zyx
from uvms_env.dynamics.uvms import NQ, PARAMETER_LAYOUT, UVMSModel
from uvms_env.models import load_parameters, render_urdf
from uvms_env.models.urdf import JOINT_NAMES, LINK_NAMES

pin = pytest.importorskip("pinocchio")

TOL = 1e-10
N_SAMPLES = 20
HYDRO_ENTRIES = (
    "vehicle_added_mass",
    "vehicle_damping_linear",
    "vehicle_damping_quadratic",
    "vehicle_extra_mass",
    "arm_added_mass_scale",
    "arm_drag_scale",
    "joint_damping",
)


def _rigid_parameters(model: UVMSModel) -> np.ndarray:
    """The nominal parameter vector with every hydrodynamic term (and joint friction)
    off; the displaced volume, hence the restoring force, stays."""
    p = model.nominal_parameters()
    for name in HYDRO_ENTRIES:
        p[PARAMETER_LAYOUT[name]] = 0.0
    return p


def _pin_model(params):
    model = pin.buildModelFromXML(render_urdf(params), pin.JointModelFreeFlyer())
    assert list(model.names)[2:] == list(JOINT_NAMES)  # same joint order as zeta
    assert model.nq == NQ + 1 and model.nv == NQ
    return model


def _pin_q(q: np.ndarray) -> np.ndarray:
    rot = np.array(rot_zyx(q[3:6]))
    quat = pin.Quaternion(rot).coeffs()  # x y z w
    return np.concatenate([q[:3], quat, q[6:]])


def _samples(seed: int = 7):
    rng = np.random.default_rng(seed)
    for _ in range(N_SAMPLES):
        q = np.concatenate(
            [rng.uniform(-2, 2, 3), rng.uniform(-1.2, 1.2, 3), rng.uniform(-2, 2, 4)]
        )
        yield q, rng.normal(0.0, 1.0, NQ)


@pytest.fixture(scope="module")
def models():
    params = load_parameters()
    return UVMSModel(params), _pin_model(params), params


def test_mass_matrix(models):
    uvms, model, params = models
    data = model.createData()
    p = _rigid_parameters(uvms)
    armature = np.diag(np.concatenate([np.zeros(6), params.arm.armature]))
    for q, _ in _samples():
        m_project = np.array(uvms.mass_matrix(q, p)) - armature
        m_pin = pin.crba(model, data, _pin_q(q))
        m_pin = np.triu(m_pin) + np.triu(m_pin, 1).T
        assert np.allclose(m_project, m_pin, rtol=0, atol=TOL), np.abs(m_project - m_pin).max()


def test_velocity_bias(models):
    """Coriolis and centrifugal terms C(q, zeta) zeta, gravity and hydrodynamics off."""
    uvms, model, _ = models
    model.gravity.linear = np.zeros(3)
    data = model.createData()
    p = _rigid_parameters(uvms)
    zero = np.zeros(3)
    for q, zeta in _samples():
        h = np.array(uvms.bias(q, zeta, zero, p)).ravel()
        h -= np.array(uvms.bias(q, np.zeros(NQ), zero, p)).ravel()  # the restoring force
        h_pin = pin.nonLinearEffects(model, data, _pin_q(q), zeta)
        assert np.allclose(h, h_pin, rtol=0, atol=TOL), np.abs(h - h_pin).max()


def _restoring_sum(model, data, q_pin: np.ndarray, params) -> np.ndarray:
    """-sum_b J_b^T f_b over the bodies of the parameter file: weight m_b g (down, +z in
    NED) at each centre of gravity, buoyancy rho V_b g (up) at each centre of buoyancy.
    The arm bodies' centres of gravity are Pinocchio's (read from the URDF); a trimmed
    arm body displaces its own mass of water, its buoyancy at its centre of gravity."""
    g, rho = params.gravity, params.water_density
    veh, arm = params.vehicle, params.arm
    pin.computeJointJacobians(model, data, q_pin)
    pin.updateFramePlacements(model, data)
    down = np.array([0.0, 0.0, 1.0])

    def point_force(frame: str, local: np.ndarray, force: np.ndarray) -> np.ndarray:
        fid = model.getFrameId(frame)
        jac = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        oMf = data.oMf[fid]
        r = oMf.rotation @ local  # from the frame origin to the point, world axes
        j_point = jac[:3] - pin.skew(r) @ jac[3:]
        return j_point.T @ force

    def volume(mass: float, datasheet: float) -> float:
        return mass / rho if arm.trim_neutral else datasheet

    weight, buoyancy = veh.mass * g, rho * veh.displaced_volume * g
    tau = point_force("vehicle", np.array(veh.center_of_gravity), weight * down)
    tau += point_force("vehicle", np.array(veh.center_of_buoyancy), -buoyancy * down)
    bodies = [("arm_base", arm.base_housing_mass, arm.base_housing_volume)]
    bodies += list(zip(LINK_NAMES, arm.link_mass, arm.link_volume, strict=True))
    for name, mass, datasheet in bodies:
        fid = model.getFrameId(name)
        if name == "arm_base":  # merged into the vehicle's body: its centre is its origin
            com = np.zeros(3)
        else:
            com = model.inertias[model.frames[fid].parentJoint].lever
        net = (mass - rho * volume(mass, datasheet)) * g
        tau += point_force(name, com, net * down)
    return -tau


@pytest.mark.parametrize("trim_neutral", [True, False], ids=["trimmed", "untrimmed"])
def test_restoring_force(trim_neutral):
    params = load_parameters()
    params = dataclasses.replace(
        params, arm=dataclasses.replace(params.arm, trim_neutral=trim_neutral)
    )
    uvms, model = UVMSModel(params), _pin_model(params)
    data = model.createData()
    p = uvms.nominal_parameters()
    for q, _ in _samples(seed=11):
        g_project = np.array(uvms.bias(q, np.zeros(NQ), np.zeros(3), p)).ravel()
        g_sum = _restoring_sum(model, data, _pin_q(q), params)
        assert np.allclose(g_project, g_sum, rtol=0, atol=TOL), np.abs(g_project - g_sum).max()
    if not trim_neutral:  # the arm's weight in water moves the joints
        assert np.abs(g_project[6:]).max() > 0.1


def test_end_effector_pose_and_jacobian(models):
    uvms, model, _ = models
    data = model.createData()
    fid = model.getFrameId("ee")
    for q, zeta in _samples():
        q_pin = _pin_q(q)
        pin.computeJointJacobians(model, data, q_pin)
        pin.updateFramePlacements(model, data)
        p_ee, r_ee = uvms.ee_pose(q)
        assert np.allclose(np.array(p_ee).ravel(), data.oMf[fid].translation, rtol=0, atol=TOL)
        assert np.allclose(np.array(r_ee), data.oMf[fid].rotation, rtol=0, atol=TOL)
        # [p_dot; omega] of the grasp frame in the inertial frame
        j_pin = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        j_project = np.array(uvms.ee_jacobian(q))
        assert np.allclose(j_project, j_pin, rtol=0, atol=TOL), np.abs(j_project - j_pin).max()
        assert np.allclose(j_project @ zeta, j_pin @ zeta, rtol=0, atol=TOL)
