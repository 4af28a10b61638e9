"""The robot as a URDF, generated from a parameter set.

Generating the URDF (rather than deriving parameters from a fixed file) lets every
"true plant" of an uncertainty study, a payload or a centre-of-mass offset have its own
robot. ``urdf/mtwip.urdf`` in the repository is this module's output for the nominal
parameters (``python -m twin.plant.urdf > urdf/mtwip.urdf``); a test keeps them equal.

Frames (SI units, right-handed, z up): the body link's frame sits at the axle midpoint
with x forward, y along the axle towards the left wheel, z up. Joint angles are the
wheel rotations relative to the body about +y, so a positive joint rate rolls a wheel
forward (+x); that is the encoder reading ψ − θ of paper-notes.

Links::

    body         mass m_b, centre of mass l above the axle (plus any offset),
                 inertia diag(n_xb, n_yb, n_zb) about its centre of mass
    wheel_left   continuous joint at (0, +b, 0), mass m_w,
    wheel_right  continuous joint at (0, -b, 0), inertia diag(n_wd, n_wa, n_wd)
    payload      optional, fixed to the body: a point-like box of the payload's mass

Collision shapes: the body is a box; each wheel collides as a sphere of radius r, so
its contact with the ground is a single point directly under the axle, the contact
the analytic model assumes (a cylinder gives Bullet a multi-point manifold that
chatters). The visuals are a cylinder per wheel, with a white spoke so rotation reads
on video.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from twin.errors import TwinError
from twin.validation import body_point
from twin.params import NOMINAL, RobotParams

WHEEL_WIDTH = 0.025  # m, visual only
WHEEL_CLEARANCE = 0.005  # m between body side and wheel, visual only
BODY_DEPTH = 0.08  # m, body box extent along x
BODY_COLOUR = (0.93, 0.49, 0.13, 1.0)  # orange: reads well on the grey checker floor
WHEEL_COLOUR = (0.12, 0.12, 0.14, 1.0)
SPOKE_COLOUR = (0.95, 0.95, 0.95, 1.0)
PAYLOAD_COLOUR = (0.15, 0.45, 0.85, 1.0)
PAYLOAD_SIZE = 0.03  # m, edge of the payload's visual cube (its inertia is a point mass's)


@dataclass(frozen=True)
class Payload:
    """A mass fixed to the body: ``mass`` in kg at ``position`` (m, body frame, from the axle midpoint)."""

    mass: float
    position: tuple[float, float, float] = (0.0, 0.0, 0.1)

    def __post_init__(self):
        m = self.mass
        if not (isinstance(m, (int, float)) and not isinstance(m, bool) and math.isfinite(m) and m > 0):
            raise TwinError(f"payload mass must be a positive number in kg, got {m!r}")
        object.__setattr__(self, "position", body_point("payload position", self.position))
        object.__setattr__(self, "mass", float(m))


def _check_offset(com_offset) -> tuple[float, float, float]:
    off = tuple(float(v) for v in com_offset)
    if len(off) != 3 or not all(math.isfinite(v) and abs(v) <= 0.1 for v in off):
        raise TwinError(f"centre-of-mass offset must be 3 finite coordinates within ±0.1 m, got {com_offset!r}")
    return off


def body_height(params: RobotParams) -> float:
    """Height of the body box in m: centred on the centre of mass, at least 12 cm."""
    return max(0.12, 2.4 * params.l)


def body_width(params: RobotParams) -> float:
    """Width (along the axle) of the body box in m, leaving room for the wheels."""
    return max(0.02, 2.0 * params.b - WHEEL_WIDTH - 2.0 * WHEEL_CLEARANCE)


def body_box(params: RobotParams, box=None) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The body box's (lowest, highest) corner in m, body frame from the axle midpoint: ``box`` where
    the robot gives one (a robot file's size and box_bottom, :attr:`twin.plant.base.TwinConfig.body`),
    else Table III's drawing rule: x within ±BODY_DEPTH/2, y within ±body_width/2, z within l ±
    body_height/2 (a centre-of-mass offset does not move it)."""
    if box is not None:
        return tuple(map(tuple, box))
    h, w = body_height(params), body_width(params)
    return (-0.5 * BODY_DEPTH, -0.5 * w, params.l - 0.5 * h), (0.5 * BODY_DEPTH, 0.5 * w, params.l + 0.5 * h)


def _f(v: float) -> str:
    return repr(float(v))


def _xyz(v) -> str:
    return " ".join(_f(c) for c in v)


def _rgba(name: str, c) -> str:
    return f'<material name="{name}"><color rgba="{_xyz(c)}"/></material>'


def _inertial(mass: float, origin, ixx: float, iyy: float, izz: float) -> str:
    return (f'<inertial><origin xyz="{_xyz(origin)}" rpy="0 0 0"/><mass value="{_f(mass)}"/>'
            f'<inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(iyy)}" iyz="0" izz="{_f(izz)}"/></inertial>')


# A cube of side 1 m centred on its origin, each face two triangles with the face's own
# normal (vertices are not shared between faces, so nothing smooths the shading).
UNIT_CUBE_OBJ = "".join(
    [f"v {x} {y} {z}\n" for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
    + ["vn 1 0 0\nvn -1 0 0\nvn 0 1 0\nvn 0 -1 0\nvn 0 0 1\nvn 0 0 -1\nvt 0 0\n"]
    + [f"f {a}/1/{n} {b}/1/{n} {c}/1/{n}\nf {a}/1/{n} {c}/1/{n} {d}/1/{n}\n"
       for n, (a, b, c, d) in enumerate(((5, 7, 8, 6), (1, 2, 4, 3), (3, 4, 8, 7), (1, 5, 6, 2), (2, 6, 8, 4),
                                         (1, 3, 7, 5)), start=1)])


def robot_urdf(params: RobotParams = NOMINAL, payload: Payload | None = None,
               com_offset=(0.0, 0.0, 0.0), name: str = "mtwip", box_mesh: str | None = None, body=None) -> str:
    """URDF text of the robot with parameters ``params``.

    Parameters
    ----------
    params : RobotParams
        Masses, inertias and geometry (Table III).
    payload : Payload, optional
        An extra mass fixed to the body.
    com_offset : (3,) m
        Offset of the body's centre of mass from (0, 0, l) in the body frame, as a
        mis-built or unevenly loaded robot has. The box geometry does not move.
    box_mesh : str, optional
        Path of a unit-cube OBJ with flat face normals (:data:`UNIT_CUBE_OBJ`) to draw every
        box *visual* with, scaled to its size, instead of URDF's box primitive: PyBullet's
        OpenGL renderer shades its box primitive with normals that leave a dark triangle
        across each face. For pictures only; collision shapes stay boxes.
    body : ((x, y, z), (x, y, z)), optional
        The body box's lowest and highest corners in m from the axle midpoint (a robot's own,
        :func:`body_box`); None: Table III's drawing rule.
    """
    off = _check_offset(com_offset)
    if payload is not None and not isinstance(payload, Payload):
        raise TwinError(f"payload must be a Payload(mass, position), got {payload!r}")
    p = params
    if body is None:  # Table III's rule, as it always was drawn
        size, centre = (BODY_DEPTH, body_width(p), body_height(p)), f"0 0 {_f(p.l)}"
    else:
        lo, hi = body_box(p, body)
        size = tuple(hi[i] - lo[i] for i in range(3))
        centre = _xyz(tuple(0.5 * (hi[i] + lo[i]) for i in range(3)))
    com = (off[0], off[1], p.l + off[2])
    spoke = (0.7 * p.r, 0.2 * WHEEL_WIDTH + 0.002, 0.12 * p.r)

    def box(size) -> str:
        if box_mesh is None:
            return f'<box size="{_xyz(size)}"/>'
        return f'<mesh filename="{box_mesh}" scale="{_xyz(size)}"/>'

    lines = [
        '<?xml version="1.0"?>',
        f'<!-- generated by twin.plant.urdf from a RobotParams set; do not edit by hand -->',
        f'<robot name="{name}">',
        '  ' + _rgba("body", BODY_COLOUR),
        '  ' + _rgba("wheel", WHEEL_COLOUR),
        '  ' + _rgba("spoke", SPOKE_COLOUR),
        '  ' + _rgba("payload", PAYLOAD_COLOUR),
        '  <link name="body">',
        '    ' + _inertial(p.m_b, com, p.n_xb, p.n_yb, p.n_zb),
        f'    <visual><origin xyz="{centre}" rpy="0 0 0"/><geometry>{box(size)}</geometry><material name="body"/></visual>',
        f'    <collision><origin xyz="{centre}" rpy="0 0 0"/><geometry><box size="{_xyz(size)}"/></geometry></collision>',
        '  </link>',
    ]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        # spoke offset outward so that it shows on the wheel's outer face
        spoke_y = sign * 0.5 * WHEEL_WIDTH
        lines += [
            f'  <link name="wheel_{side}">',
            '    ' + _inertial(p.m_w, (0.0, 0.0, 0.0), p.n_wd, p.n_wa, p.n_wd),
            f'    <visual><origin xyz="0 0 0" rpy="{_f(math.pi / 2)} 0 0"/><geometry><cylinder radius="{_f(p.r)}" length="{_f(WHEEL_WIDTH)}"/></geometry><material name="wheel"/></visual>',
            f'    <visual><origin xyz="{_f(0.35 * p.r)} {_f(spoke_y)} 0" rpy="0 0 0"/><geometry>{box(spoke)}</geometry><material name="spoke"/></visual>',
            f'    <collision><origin xyz="0 0 0" rpy="0 0 0"/><geometry><sphere radius="{_f(p.r)}"/></geometry></collision>',
            '  </link>',
            f'  <joint name="wheel_{side}_joint" type="continuous">',
            '    <parent link="body"/>',
            f'    <child link="wheel_{side}"/>',
            f'    <origin xyz="0 {_f(sign * p.b)} 0" rpy="0 0 0"/>',
            '    <axis xyz="0 1 0"/>',
            # damping is applied by the twin as equation (1) states, not by the engine
            '    <dynamics damping="0" friction="0"/>',
            '  </joint>',
        ]
    if payload is not None:
        # a point mass: a tiny inertia keeps the multibody well conditioned
        tiny = payload.mass * (PAYLOAD_SIZE ** 2) / 6.0
        lines += [
            '  <link name="payload">',
            '    ' + _inertial(payload.mass, (0.0, 0.0, 0.0), tiny, tiny, tiny),
            f'    <visual><origin xyz="0 0 0" rpy="0 0 0"/><geometry>{box((PAYLOAD_SIZE,) * 3)}</geometry><material name="payload"/></visual>',
            '  </link>',
            '  <joint name="payload_joint" type="fixed">',
            '    <parent link="body"/>',
            '    <child link="payload"/>',
            f'    <origin xyz="{_xyz(payload.position)}" rpy="0 0 0"/>',
            '  </joint>',
        ]
    lines.append('</robot>')
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # regenerate urdf/mtwip.urdf
    import sys

    sys.stdout.write(robot_urdf())
