"""Write ``usd/cartpole.usda``: the classic Isaac cartpole authored with UsdPhysics schemas.

Run: ``python usd/make_cartpole.py [output.usda]`` (default: next to this script).

Geometry and masses are the physical facts of the classic Isaac cartpole; every inertia tensor is
derived from its box and mass here and authored on the stage, so simulators read it rather than guess.
Up axis Z, metres, kilograms. The rail lies along Y; the cart slides along Y; the pole hinges about X.
"""

import sys
from pathlib import Path

from pxr import Gf, Usd, UsdGeom, UsdPhysics

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


def box_inertia(mass_kg, size_m):
    """Principal moments (kg m^2) of a solid box about its centre."""
    x, y, z = size_m
    return (mass_kg * (y * y + z * z) / 12.0, mass_kg * (x * x + z * z) / 12.0, mass_kg * (x * x + y * y) / 12.0)


def _body(stage, path, translate, box_size, box_center, mass_kg, color):
    body = UsdGeom.Xform.Define(stage, path)
    body.AddTranslateOp().Set(Gf.Vec3d(*translate))
    UsdPhysics.RigidBodyAPI.Apply(body.GetPrim())
    mass = UsdPhysics.MassAPI.Apply(body.GetPrim())
    mass.CreateMassAttr(mass_kg)
    mass.CreateCenterOfMassAttr(Gf.Vec3f(*box_center))
    mass.CreateDiagonalInertiaAttr(Gf.Vec3f(*box_inertia(mass_kg, box_size)))
    mass.CreatePrincipalAxesAttr(Gf.Quatf(1.0))
    geom = UsdGeom.Cube.Define(stage, f"{path}/geom")
    geom.CreateSizeAttr(1.0)
    geom.AddTranslateOp().Set(Gf.Vec3d(*box_center))
    geom.AddScaleOp().Set(Gf.Vec3f(*box_size))
    geom.CreateDisplayColorAttr([Gf.Vec3f(*color)])
    UsdPhysics.CollisionAPI.Apply(geom.GetPrim())
    return body


def build_stage():
    """Author the cartpole stage in memory and return it."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)

    scene = UsdPhysics.Scene.Define(stage, "/physicsScene")
    scene.CreateGravityDirectionAttr(Gf.Vec3f(0.0, 0.0, -1.0))
    scene.CreateGravityMagnitudeAttr(GRAVITY_M_S2)

    root = UsdGeom.Xform.Define(stage, "/cartpole")
    stage.SetDefaultPrim(root.GetPrim())
    UsdPhysics.ArticulationRootAPI.Apply(root.GetPrim())

    rail = _body(stage, "/cartpole/rail", (0, 0, 0), RAIL_SIZE_M, (0, 0, 0), 1.0, COLORS["rail"])
    cart = _body(stage, "/cartpole/cart", (0, 0, 0), CART_SIZE_M, (0, 0, 0), CART_MASS_KG, COLORS["cart"])
    pole = _body(stage, "/cartpole/pole", (HINGE_OFFSET_FROM_CART_M, 0, 0), POLE_SIZE_M,
                 (0, 0, POLE_COM_ABOVE_HINGE_M), POLE_MASS_KG, COLORS["pole"])

    fixed = UsdPhysics.FixedJoint.Define(stage, "/cartpole/railJoint")
    fixed.CreateBody1Rel().SetTargets([rail.GetPath()])

    cart_joint = UsdPhysics.PrismaticJoint.Define(stage, "/cartpole/cartJoint")
    cart_joint.CreateBody0Rel().SetTargets([rail.GetPath()])
    cart_joint.CreateBody1Rel().SetTargets([cart.GetPath()])
    cart_joint.CreateAxisAttr(UsdPhysics.Tokens.y)
    cart_joint.CreateLowerLimitAttr(-CART_TRAVEL_LIMIT_M)
    cart_joint.CreateUpperLimitAttr(CART_TRAVEL_LIMIT_M)

    pole_joint = UsdPhysics.RevoluteJoint.Define(stage, "/cartpole/poleJoint")
    pole_joint.CreateBody0Rel().SetTargets([cart.GetPath()])
    pole_joint.CreateBody1Rel().SetTargets([pole.GetPath()])
    pole_joint.CreateAxisAttr(UsdPhysics.Tokens.x)
    pole_joint.CreateLocalPos0Attr(Gf.Vec3f(HINGE_OFFSET_FROM_CART_M, 0.0, 0.0))
    pole_joint.CreateLocalPos1Attr(Gf.Vec3f(0.0, 0.0, 0.0))
    return stage


def stage_text():
    """The stage as USDA text, exactly as ``main`` writes it."""
    stage = build_stage()
    return stage.GetRootLayer().ExportToString()


def main():
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("cartpole.usda")
    out.write_text(stage_text())
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
