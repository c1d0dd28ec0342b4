"""The committed stage is what usd/make_cartpole.py writes (``engine.stages``), and it holds the cartpole's physical
facts."""

import pytest
from pxr import Usd, UsdGeom, UsdPhysics

from cartpole_warp.engine import stages
from cartpole_warp.settings.files import data_path

STAGE = data_path("usd", "cartpole.usda")


def test_committed_stage_matches_the_script(repo):
    assert repo / "usd" / "cartpole.usda" == STAGE, "a checkout uses the stage at the top of the repository"
    assert STAGE.read_text() == stages.stage_text(), "run: python usd/make_cartpole.py"


def test_stage_schemas_and_facts():
    stage = Usd.Stage.Open(str(STAGE))
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().HasAPI(UsdPhysics.ArticulationRootAPI)
    cart_joint = UsdPhysics.PrismaticJoint(stage.GetPrimAtPath("/cartpole/cartJoint"))
    assert cart_joint and cart_joint.GetAxisAttr().Get() == "Y"
    assert (cart_joint.GetLowerLimitAttr().Get(), cart_joint.GetUpperLimitAttr().Get()) == (-4.0, 4.0)
    pole_joint = UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/cartpole/poleJoint"))
    assert pole_joint and pole_joint.GetAxisAttr().Get() == "X"
    assert tuple(pole_joint.GetLocalPos0Attr().Get()) == pytest.approx((0.12, 0.0, 0.0))
    fixed = UsdPhysics.FixedJoint(stage.GetPrimAtPath("/cartpole/railJoint"))
    assert fixed and fixed.GetBody1Rel().GetTargets()[0] == "/cartpole/rail"
    bodies = [("cart", 1.0, (0.2, 0.25, 0.2)), ("pole", 1.0, (0.04, 0.06, 1.0)), ("rail", 1.0, (0.03, 8, 0.03))]
    for body, mass, size in bodies:
        prim = stage.GetPrimAtPath(f"/cartpole/{body}")
        assert prim.HasAPI(UsdPhysics.RigidBodyAPI)
        assert UsdPhysics.MassAPI(prim).GetMassAttr().Get() == mass
        geom = stage.GetPrimAtPath(f"/cartpole/{body}/geom")
        assert geom.HasAPI(UsdPhysics.CollisionAPI)
        assert tuple(UsdGeom.Cube(geom).GetDisplayColorAttr().Get()[0]) != (0, 0, 0)
        scale = geom.GetAttribute("xformOp:scale").Get()
        assert tuple(scale) == pytest.approx(size)
        x, y, z = size
        inertia = UsdPhysics.MassAPI(prim).GetDiagonalInertiaAttr().Get()
        box = (mass * (y * y + z * z) / 12, mass * (x * x + z * z) / 12, mass * (x * x + y * y) / 12)
        assert tuple(inertia) == pytest.approx(box, rel=1e-5)
    pole_com = UsdPhysics.MassAPI(stage.GetPrimAtPath("/cartpole/pole")).GetCenterOfMassAttr().Get()
    assert tuple(pole_com) == pytest.approx((0.0, 0.0, 0.47))
