"""``import vdad`` loads no renderer, GL, oracle or mesh library (DEVELOPERS: model only
what a scene needs)."""

from imports import loaded


def test_import_is_light():
    code = ("import vdad, vdad.scenes, vdad.cli, vdad.reproduce, vdad.visual_error, "
            "vdad.sweep, vdad.baselines")
    assert loaded(code, ("pyrender", "OpenGL", "mujoco", "pinocchio", "trimesh", "matplotlib",
                         "joblib", "dask", "distributed")) == "[]"
