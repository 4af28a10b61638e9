"""The robot's URDF: read back with yourdfpy (and PyBullet) and checked against the parameter set."""
import io
from pathlib import Path

import numpy as np
import pytest
import yourdfpy

from twin.errors import TwinError
from twin.params import NOMINAL
from twin.plant.bullet import BulletTwin, TwinConfig
from twin.plant.disturbances import sample_plant
from twin.plant.urdf import Payload, robot_urdf

REPO_URDF = Path(__file__).resolve().parents[1] / "urdf" / "mtwip.urdf"
PERTURBED = sample_plant(NOMINAL, np.random.default_rng(7), spread=0.3)


def _load(text: str) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.StringIO(text), load_meshes=False, build_scene_graph=False)


def _link(urdf, name):
    return next(link for link in urdf.robot.links if link.name == name)


def _joint(urdf, name):
    return next(j for j in urdf.robot.joints if j.name == name)


def test_committed_urdf_is_the_generated_nominal_robot():
    """urdf/mtwip.urdf is regenerated from NOMINAL (python -m twin.plant.urdf), never edited by hand."""
    assert REPO_URDF.read_text() == robot_urdf(NOMINAL)


@pytest.mark.parametrize("params", [NOMINAL, PERTURBED], ids=["nominal", "perturbed"])
def test_masses_inertias_and_geometry_match_the_parameters(params):
    """Body: m_b, diag(n_xb, n_yb, n_zb) at l above the axle; wheels: m_w, diag(n_wd, n_wa, n_wd), radius r, at ±b."""
    u = _load(robot_urdf(params))
    body = _link(u, "body")
    assert body.inertial.mass == pytest.approx(params.m_b, rel=1e-12)
    np.testing.assert_allclose(np.diag(body.inertial.inertia), [params.n_xb, params.n_yb, params.n_zb], rtol=1e-12)
    np.testing.assert_allclose(body.inertial.inertia - np.diag(np.diag(body.inertial.inertia)), 0.0)
    np.testing.assert_allclose(body.inertial.origin[:3, 3], [0.0, 0.0, params.l], rtol=1e-12)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        wheel = _link(u, f"wheel_{side}")
        assert wheel.inertial.mass == pytest.approx(params.m_w, rel=1e-12)
        np.testing.assert_allclose(np.diag(wheel.inertial.inertia), [params.n_wd, params.n_wa, params.n_wd], rtol=1e-12)
        np.testing.assert_allclose(wheel.inertial.origin[:3, 3], 0.0)
        (coll,) = wheel.collisions
        assert coll.geometry.sphere.radius == pytest.approx(params.r, rel=1e-12)
        assert wheel.visuals[0].geometry.cylinder.radius == pytest.approx(params.r, rel=1e-12)
        joint = _joint(u, f"wheel_{side}_joint")
        assert joint.type == "continuous" and joint.parent == "body" and joint.child == f"wheel_{side}"
        np.testing.assert_allclose(joint.axis, [0.0, 1.0, 0.0])
        np.testing.assert_allclose(joint.origin[:3, 3], [0.0, sign * params.b, 0.0], rtol=1e-12)
    left, right = (_joint(u, f"wheel_{s}_joint").origin[:3, 3] for s in ("left", "right"))
    assert np.linalg.norm(left - right) == pytest.approx(2 * params.b, rel=1e-12)


def test_payload_and_com_offset_change_the_robot():
    """A payload is a fixed link of its mass at its position; a COM offset moves the body's inertial origin."""
    u = _load(robot_urdf(NOMINAL, Payload(0.4, (0.02, -0.01, 0.12)), com_offset=(0.003, 0.0, -0.002)))
    np.testing.assert_allclose(_link(u, "body").inertial.origin[:3, 3], [0.003, 0.0, NOMINAL.l - 0.002], rtol=1e-12)
    assert _link(u, "payload").inertial.mass == pytest.approx(0.4)
    joint = _joint(u, "payload_joint")
    assert joint.type == "fixed" and joint.parent == "body"
    np.testing.assert_allclose(joint.origin[:3, 3], [0.02, -0.01, 0.12])
    assert all(link.name != "payload" for link in _load(robot_urdf(NOMINAL)).robot.links)


def test_colours_tell_body_and_wheels_apart():
    """Every visual has a named material with a colour; the body and the wheels differ."""
    u = _load(robot_urdf(NOMINAL))
    colours = {m.name: np.asarray(m.color.rgba) for m in u.robot.materials}
    assert np.linalg.norm(colours["body"][:3] - colours["wheel"][:3]) > 0.5
    for link in u.robot.links:
        for v in link.visuals:
            assert v.material is not None and v.material.name in colours


def test_pybullet_uses_the_urdf_inertias():
    """PyBullet recomputes inertia from collision shapes unless told otherwise: check what it simulates."""
    params = PERTURBED
    with BulletTwin(TwinConfig(params=params)) as twin:
        c = twin.client
        body = c.getDynamicsInfo(twin.robot, -1)
        assert body[0] == pytest.approx(params.m_b)
        np.testing.assert_allclose(body[2], [params.n_xb, params.n_yb, params.n_zb], rtol=1e-9)
        np.testing.assert_allclose(body[3], [0.0, 0.0, params.l], rtol=1e-9)
        for j in (0, 1):
            wheel = c.getDynamicsInfo(twin.robot, j)
            assert wheel[0] == pytest.approx(params.m_w)
            np.testing.assert_allclose(wheel[2], [params.n_wd, params.n_wa, params.n_wd], rtol=1e-9)


def test_bad_urdf_inputs_are_clear_errors():
    with pytest.raises(TwinError, match="centre-of-mass offset"):
        robot_urdf(NOMINAL, com_offset=(0.0, 0.5, 0.0))
    with pytest.raises(TwinError, match="payload"):
        robot_urdf(NOMINAL, payload=(0.3, (0, 0, 0.1)))
    with pytest.raises(TwinError, match="payload mass"):
        Payload(-1.0)
    with pytest.raises(TwinError, match="payload position"):
        Payload(0.2, (0.0, 0.0, float("nan")))
