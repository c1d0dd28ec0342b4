"""The cart-pole stages authored from their physical facts with UsdPhysics schemas (the package's ``usd/*.usda`` are
what these functions write; ``usd/make_cartpole.py`` writes them): the classic Isaac cartpole (``stage_text()``),
dm_control's cartpole (``dmc_stage_text(n)``: the model of its ``swingup`` task, and for n = 2, 3 of its
``_make_model(n_poles)``, a chain of n identical poles, each hinged at the top of the one below: ``two_poles``,
``three_poles``), and the multi-arm pendulum rig with 1, 2 or 3 arms (``multiarm_stage_text(n)``). A stage of your
own: a ``Cartpole`` with its ``Arm``s, and ``stage_text(spec)``.

Every stage follows one convention, so the same loader and the same closed-form check apply: up axis Z, metres,
kilograms; the articulation root on /cartpole; a fixed rail body (``railJoint``); the cart slides along Y
(PrismaticJoint ``cartJoint``); the pole hinges about X (RevoluteJoint ``poleJoint``), upright at angle 0. Every
body's mass, centre of mass and diagonal inertia are authored (MassAPI), derived here from its shape and mass, so
simulators read them rather than guess.

The classic Isaac cartpole: boxes; cart 1 kg, 0.2 x 0.25 x 0.2 m; pole 1 kg, 0.04 x 0.06 x 1 m, its centre of mass
0.47 m above the hinge, which sits 0.12 m off the cart centre along X; cart travel +-4 m; gravity 9.81 m/s^2.

dm_control's cartpole (``dm_control/suite/cartpole.xml``): cart box 0.4 x 0.3 x 0.2 m (MuJoCo half-sizes
0.2 0.15 0.1, its long side along the slide), 1 kg; pole capsule ``fromto="0 0 0 0 0 1"`` of radius 0.045 m, 0.1 kg,
its centre of mass 0.5 m above the hinge at the cart centre, with MuJoCo's capsule inertia (``capsule_inertia``);
slider range +-1.8 m; gravity 9.81 m/s^2 (MuJoCo's default). The XML slides along X and hinges about Y; here the
slide is along Y and the hinge about X, so a positive pole angle tips the pole towards -Y (towards -slide), where
dm_control's positive hinge angle tips it towards +slide: the angle's sign is flipped, its cosine is not. Not
modelled: the joint dampings (slider 5e-4 N s/m, hinge 2e-6 N m s/rad), the slider limit's ``solreflimit=".08 1"``
(a critically damped limit spring of Newton's stands for it: ``DMC_LIMIT_STIFFNESS_N_M``),
the actuator (a motor of gear 10 with ``ctrlrange="-1 1"``, i.e. up to 10 N on the cart: the env applies the force),
the timestep (0.01 s, RK4), and the two decorative rail capsules (radius 0.02 m, 4 m long, 0.14 m apart), for which
one 0.04 x 4 x 0.04 m box stands. In a chain, pole k (body ``pole<k>``, joint ``pole<k>Joint`` about X, k >= 2) hinges
1 m above pole k-1's hinge, where dm_control puts ``pole_<k>`` (``pos="0 0 1"``); dm_control disables contacts, and
Newton's scenes here compute none, so the poles pass through each other as there.
"""

import dataclasses
import itertools
import math
from dataclasses import dataclass

from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics

from ..settings.config import require

GRAVITY_M_S2 = 9.81
RAIL_SIZE_M = (0.03, 8.0, 0.03)
CART_SIZE_M = (0.2, 0.25, 0.2)
CART_MASS_KG = 1.0
CART_TRAVEL_LIMIT_M = 4.0
POLE_SIZE_M = (0.04, 0.06, 1.0)
POLE_MASS_KG = 1.0
POLE_COM_ABOVE_HINGE_M = 0.47
HINGE_OFFSET_FROM_CART_M = 0.12
COLORS = {"rail": (0.35, 0.35, 0.38), "cart": (0.15, 0.45, 0.85), "pole": (0.9, 0.55, 0.1)}

DMC_RAIL_SIZE_M = (0.04, 4.0, 0.04)
DMC_CART_SIZE_M = (0.3, 0.4, 0.2)
DMC_CART_MASS_KG = 1.0
DMC_CART_TRAVEL_LIMIT_M = 1.8
DMC_POLE_RADIUS_M = 0.045
DMC_POLE_LENGTH_M = 1.0
DMC_POLE_MASS_KG = 0.1
DMC_COLORS = {"rail": (0.3, 0.5, 0.7), "cart": (0.7, 0.5, 0.3), "pole": (0.7, 0.5, 0.3)}
"""dm_control's materials: ``decoration`` for the rails, ``self`` for the cart and the pole."""
DMC_LIMIT_STIFFNESS_N_M = 2500.0
"""The slider's limits as a critically damped spring (damping 2 sqrt(stiffness x (cart + pole mass))): the cart stops
at +-1.8 m (4 mm deep under the full 10 N) instead of bouncing back, as dm_control's ``solreflimit=".08 1"``
(damping ratio 1) makes it; Newton's default limit (1e4 N/m, 10 N s/m) is damped 5% of critical and throws the cart
back at nearly its speed. Soft enough for an explicit 0.01 s step."""
MUJOCO_SOLREFLIMIT = (0.02, 1.0)
"""MuJoCo's default limit solref (time constant 0.02 s, damping ratio 1) for SolverMuJoCo, which reads ``mjc:``
attributes rather than Newton's limit spring (from that spring it makes a softer constraint: the cart went 0.7 m past
1.8 m)."""
RAIL_MASS_KG = 1.0
"""The rail is fixed to the world, so its mass never enters the dynamics."""


def box_inertia(mass_kg, size_m):
    """Principal moments (kg m^2) of a solid box about its centre."""
    x, y, z = size_m
    return (mass_kg * (y * y + z * z) / 12.0, mass_kg * (x * x + z * z) / 12.0, mass_kg * (x * x + y * y) / 12.0)


def capsule_inertia(mass_kg, radius_m, height_m):
    """Principal moments (kg m^2) about its centre of a solid capsule along Z, as MuJoCo computes them for a capsule
    geom (``mjCGeom::SetInertia``, volume inertia): a cylinder of length ``height_m`` and two hemispherical caps of
    radius ``radius_m``, one density throughout.

    With r the radius and h the cylinder's length, the caps (one sphere) take m_s = m 4r / (4r + 3h) of the mass and
    the cylinder m_c = m - m_s. Across the axis: m_c (3r^2 + h^2) / 12 + 2 m_s r^2 / 5 + m_s h (3r + 2h) / 8 (each
    hemisphere's own moment, moved by the parallel-axis theorem from its centre of mass 3r/8 beyond the cylinder's
    end); along the axis: m_c r^2 / 2 + 2 m_s r^2 / 5.
    """
    r, h = radius_m, height_m
    sphere = mass_kg * 4.0 * r / (4.0 * r + 3.0 * h)
    cylinder = mass_kg - sphere
    caps_own = 2.0 * sphere * r * r / 5.0
    across = cylinder * (3.0 * r * r + h * h) / 12.0 + caps_own + sphere * h * (3.0 * r + 2.0 * h) / 8.0
    along = cylinder * r * r / 2.0 + caps_own
    return (across, across, along)


@dataclass(frozen=True)
class Box:
    """A solid box of ``size_m`` (a unit Cube scaled to it)."""

    size_m: tuple

    def inertia(self, mass_kg):
        return box_inertia(mass_kg, self.size_m)

    def define(self, stage, path, center):
        geom = UsdGeom.Cube.Define(stage, path)
        geom.CreateSizeAttr(1.0)
        geom.AddTranslateOp().Set(Gf.Vec3d(*center))
        geom.AddScaleOp().Set(Gf.Vec3f(*self.size_m))
        return geom


@dataclass(frozen=True)
class Capsule:
    """A solid capsule along Z: a cylinder of ``height_m`` (UsdGeom's height, caps excluded) capped by hemispheres of
    ``radius_m``."""

    radius_m: float
    height_m: float

    def inertia(self, mass_kg):
        return capsule_inertia(mass_kg, self.radius_m, self.height_m)

    def define(self, stage, path, center):
        geom = UsdGeom.Capsule.Define(stage, path)
        geom.CreateAxisAttr(UsdGeom.Tokens.z)
        geom.CreateRadiusAttr(self.radius_m)
        geom.CreateHeightAttr(self.height_m)
        geom.AddTranslateOp().Set(Gf.Vec3d(*center))
        return geom


@dataclass(frozen=True)
class Cartpole:
    """The physical facts of one cartpole stage."""

    rail: Box
    cart: Box
    cart_mass_kg: float
    pole: Box | Capsule
    pole_mass_kg: float
    pole_com_above_hinge_m: float
    hinge_offset_from_cart_m: float
    """Along X, from the cart's centre to the hinge (and the pole body's origin)."""
    cart_travel_limit_m: float
    colors: dict
    gravity_m_s2: float = GRAVITY_M_S2
    cart_limit_stiffness_n_m: float | None = None
    """Newton's ``newton:limitStiffness`` of the slider's limits (None: Newton's default, 1e4 N/m, with 10 N s/m)."""
    cart_limit_damping_n_s_m: float | None = None
    """Newton's ``newton:limitDamping`` of the slider's limits."""
    num_poles: int = 1
    """Poles in a chain, each ``pole_spacing_m`` above the one below (its hinge at the other's top)."""
    pole_spacing_m: float = 1.0
    """From one pole's hinge to the next one's (m), along the pole."""
    arms: tuple = ()
    """Poles that differ (``Arm``s, from the cart up), in place of ``num_poles`` copies of ``pole``."""

    def chain(self) -> tuple:
        """The poles from the cart up, as ``Arm``s."""
        return self.arms or (Arm(self.pole, self.pole_mass_kg, self.pole_com_above_hinge_m, self.pole_spacing_m),
                             ) * self.num_poles


@dataclass(frozen=True)
class Arm:
    """One pole of a chain: its shape (centred on its centre of mass), mass, centre of mass above its hinge and the
    distance from its hinge to the next pole's (m)."""

    shape: Box | Capsule
    mass_kg: float
    com_above_hinge_m: float
    spacing_m: float


CLASSIC = Cartpole(rail=Box(RAIL_SIZE_M), cart=Box(CART_SIZE_M), cart_mass_kg=CART_MASS_KG, pole=Box(POLE_SIZE_M),
                   pole_mass_kg=POLE_MASS_KG, pole_com_above_hinge_m=POLE_COM_ABOVE_HINGE_M,
                   hinge_offset_from_cart_m=HINGE_OFFSET_FROM_CART_M, cart_travel_limit_m=CART_TRAVEL_LIMIT_M,
                   colors=COLORS)
DMC = Cartpole(rail=Box(DMC_RAIL_SIZE_M), cart=Box(DMC_CART_SIZE_M), cart_mass_kg=DMC_CART_MASS_KG,
               pole=Capsule(DMC_POLE_RADIUS_M, DMC_POLE_LENGTH_M), pole_mass_kg=DMC_POLE_MASS_KG,
               pole_com_above_hinge_m=DMC_POLE_LENGTH_M / 2, hinge_offset_from_cart_m=0.0,
               cart_travel_limit_m=DMC_CART_TRAVEL_LIMIT_M, colors=DMC_COLORS,
               cart_limit_stiffness_n_m=DMC_LIMIT_STIFFNESS_N_M,
               cart_limit_damping_n_s_m=2.0 * math.sqrt(DMC_LIMIT_STIFFNESS_N_M
                                                        * (DMC_CART_MASS_KG + DMC_POLE_MASS_KG)))


MULTIARM_ARM_SECTION_M = (0.0127, 0.03175)
"""The multi-arm pendulum's arms (Kaheman et al., HardwareX 2023, dynamicslab/MultiArm-Pendulum, ``CAD
Files/Drawing/Arm1.pdf``): a machined U-channel of 12.7 mm along the hinge's axis by 31.75 mm across, drawn here as a
solid box of that section (the stage's inertia: a shape that the fit's inertia scale corrects)."""
MULTIARM_ARM_LENGTHS_M = (0.220, 0.27588, 0.2413)
"""Each arm's overall length, from the cart up: ``Arm1.pdf`` 219.999 mm, ``Arm2.pdf`` 10.8614 in, and arm 3's 0.2413 m
of the authors' ``TriplePendulumSimWithX0.m`` (``L3``)."""
MULTIARM_SPACINGS_M = (0.17272, 0.2286)
"""From arm 1's hinge on the cart to arm 2's (``Arm1.pdf``, 6.80 in) and from arm 2's to arm 3's (``Arm2.pdf``,
9.00 in)."""
MULTIARM_HUB_M = (MULTIARM_ARM_LENGTHS_M[0] - MULTIARM_SPACINGS_M[0]) / 2
"""How far an arm's hub reaches beyond its hinges (arms 1 and 2 alike, 23.6 mm); arm 3, the top one, is drawn the
same way: as if its far hub held a hinge."""
MULTIARM_MASSES_KG = {1: (0.147585,), 2: (0.093844, 0.137596), 3: (0.258172, 0.279428, 0.118624)}
"""Each rig's arms' masses: the repository's estimates (``EstimatedParameters_<Single|Double|Triple>Pendulum.mat``),
which no drawing states (each rig's arms carry their own encoders and bearings). A free swing cannot tell them
(scaling every mass and inertia with the damping and friction moves nothing): they fix that scale, and the fit
finds the rest."""
MULTIARM_COLORS = {"rail": (0.35, 0.35, 0.38), "cart": (0.2, 0.2, 0.22), "pole": (0.75, 0.75, 0.78)}


def multiarm_arms(num_arms: int) -> tuple:
    """The rig of ``num_arms`` arms as ``Arm``s from the cart up: each a box of the channel's section and its overall
    length, centred between its hinges (ConfigError in one line for a chain the repository holds no rig of)."""
    rigs = ", ".join(map(str, MULTIARM_MASSES_KG))
    require(num_arms in MULTIARM_MASSES_KG, f"the multi-arm pendulum's rigs have {rigs} arms; no stage of {num_arms}")
    spacings = (*MULTIARM_SPACINGS_M, MULTIARM_ARM_LENGTHS_M[2] - 2 * MULTIARM_HUB_M)
    return tuple(Arm(Box((*MULTIARM_ARM_SECTION_M, length)), mass, spacing / 2, spacing)
                 for length, spacing, mass in zip(MULTIARM_ARM_LENGTHS_M, spacings, MULTIARM_MASSES_KG[num_arms]))


MULTIARM = Cartpole(rail=Box((0.03, 1.2, 0.03)), cart=Box((0.1, 0.12, 0.05)), cart_mass_kg=1.0,
                    pole=multiarm_arms(1)[0].shape, pole_mass_kg=multiarm_arms(1)[0].mass_kg,
                    pole_com_above_hinge_m=multiarm_arms(1)[0].com_above_hinge_m, hinge_offset_from_cart_m=0.0,
                    cart_travel_limit_m=0.5, colors=MULTIARM_COLORS)
"""The multi-arm pendulum on its cart. The cart and its rail stand in for the rig's (no drawing gives the cart's
mass): the recordings here hold the cart still (``sim.held_joints``), where they do not enter."""


def _body(stage, path, translate, shape, shape_center, mass_kg, color):
    """A rigid body with its mass properties authored and one shown collision shape centred on its centre of mass."""
    body = UsdGeom.Xform.Define(stage, path)
    body.AddTranslateOp().Set(Gf.Vec3d(*translate))
    UsdPhysics.RigidBodyAPI.Apply(body.GetPrim())
    mass = UsdPhysics.MassAPI.Apply(body.GetPrim())
    mass.CreateMassAttr(mass_kg)
    mass.CreateCenterOfMassAttr(Gf.Vec3f(*shape_center))
    mass.CreateDiagonalInertiaAttr(Gf.Vec3f(*shape.inertia(mass_kg)))
    mass.CreatePrincipalAxesAttr(Gf.Quatf(1.0))
    geom = shape.define(stage, f"{path}/geom", shape_center)
    geom.CreateDisplayColorAttr([Gf.Vec3f(*color)])
    UsdPhysics.CollisionAPI.Apply(geom.GetPrim())
    return body


def build_stage(spec: Cartpole = CLASSIC):
    """Author the cartpole stage of ``spec`` in memory and return it."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)

    scene = UsdPhysics.Scene.Define(stage, "/physicsScene")
    scene.CreateGravityDirectionAttr(Gf.Vec3f(0.0, 0.0, -1.0))
    scene.CreateGravityMagnitudeAttr(spec.gravity_m_s2)

    root = UsdGeom.Xform.Define(stage, "/cartpole")
    stage.SetDefaultPrim(root.GetPrim())
    UsdPhysics.ArticulationRootAPI.Apply(root.GetPrim())

    hinge = (spec.hinge_offset_from_cart_m, 0, 0)
    rail = _body(stage, "/cartpole/rail", (0, 0, 0), spec.rail, (0, 0, 0), RAIL_MASS_KG, spec.colors["rail"])
    cart = _body(stage, "/cartpole/cart", (0, 0, 0), spec.cart, (0, 0, 0), spec.cart_mass_kg, spec.colors["cart"])
    arms = spec.chain()
    heights = itertools.accumulate((arm.spacing_m for arm in arms[:-1]), initial=0.0)  # hinges above the cart's
    poles = [_body(stage, f"/cartpole/{pole_name(k)}", (hinge[0], 0, height), arm.shape,
                   (0, 0, arm.com_above_hinge_m), arm.mass_kg, spec.colors["pole"])
             for k, (arm, height) in enumerate(zip(arms, heights), start=1)]

    fixed = UsdPhysics.FixedJoint.Define(stage, "/cartpole/railJoint")
    fixed.CreateBody1Rel().SetTargets([rail.GetPath()])

    cart_joint = UsdPhysics.PrismaticJoint.Define(stage, "/cartpole/cartJoint")
    cart_joint.CreateBody0Rel().SetTargets([rail.GetPath()])
    cart_joint.CreateBody1Rel().SetTargets([cart.GetPath()])
    cart_joint.CreateAxisAttr(UsdPhysics.Tokens.y)
    cart_joint.CreateLowerLimitAttr(-spec.cart_travel_limit_m)
    cart_joint.CreateUpperLimitAttr(spec.cart_travel_limit_m)
    if spec.cart_limit_stiffness_n_m is not None:
        prim = cart_joint.GetPrim()
        prim.CreateAttribute("newton:limitStiffness", Sdf.ValueTypeNames.Float).Set(spec.cart_limit_stiffness_n_m)
        prim.CreateAttribute("newton:limitDamping", Sdf.ValueTypeNames.Float).Set(spec.cart_limit_damping_n_s_m)
        prim.CreateAttribute("mjc:solreflimit", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(*MUJOCO_SOLREFLIMIT))

    pole_joints(stage, hinge, arms, [cart, *poles])
    return stage


def pole_joints(stage, hinge: tuple, arms: tuple, bodies: list):
    """Each pole's revolute joint about X: the first at ``hinge`` on the cart (``bodies[0]``), each further one at the
    top of the pole below (its ``spacing_m``)."""
    for k, (parent, pole) in enumerate(zip(bodies, bodies[1:]), start=1):
        pole_joint = UsdPhysics.RevoluteJoint.Define(stage, f"/cartpole/{pole_name(k)}Joint")
        pole_joint.CreateBody0Rel().SetTargets([parent.GetPath()])
        pole_joint.CreateBody1Rel().SetTargets([pole.GetPath()])
        pole_joint.CreateAxisAttr(UsdPhysics.Tokens.x)
        pole_joint.CreateLocalPos0Attr(Gf.Vec3f(*hinge) if k == 1 else Gf.Vec3f(0.0, 0.0, arms[k - 2].spacing_m))
        pole_joint.CreateLocalPos1Attr(Gf.Vec3f(0.0, 0.0, 0.0))


def pole_name(k: int) -> str:
    """The body of the k-th pole from the cart (1-based): ``pole``, ``pole2``, ``pole3``, ... (its joint: + Joint)."""
    return "pole" if k == 1 else f"pole{k}"


def stage_text(spec: Cartpole = CLASSIC):
    """The stage of ``spec`` (default: the classic cartpole) as USDA text, exactly as ``usd/make_cartpole.py`` writes
    it."""
    stage = build_stage(spec)  # held: the layer lives only as long as its stage
    return stage.GetRootLayer().ExportToString()


def dmc_stage_text(num_poles: int = 1):
    """dm_control's cartpole stage with a chain of ``num_poles`` poles as USDA text, exactly as ``usd/make_cartpole.py``
    writes it."""
    return stage_text(dataclasses.replace(DMC, num_poles=num_poles, pole_spacing_m=DMC_POLE_LENGTH_M))


CHAINS = (2, 3)
"""The pole counts of the chain stages (``cartpole_dmc_<n>poles.usda``)."""


MULTIARM_STAGES = {1: "multiarm_pendulum.usda", 2: "multiarm_pendulum_2arms.usda", 3: "multiarm_pendulum_3arms.usda"}
"""The rig's stage file of each chain length (in the package's ``usd/``)."""


def multiarm_stage_text(num_arms: int):
    """The multi-arm pendulum rig's stage with ``num_arms`` arms and that rig's masses (``multiarm_arms``) as USDA
    text, exactly as ``usd/make_cartpole.py`` writes it."""
    return stage_text(dataclasses.replace(MULTIARM, arms=multiarm_arms(num_arms)))
