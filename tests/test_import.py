"""``import vdad`` loads no renderer, GL, oracle or mesh library (DEVELOPERS: model only
what a scene needs)."""

import subprocess
import sys


def test_import_is_light():
    code = ("import sys, vdad, vdad.scenes, vdad.cli, vdad.reproduce, vdad.visual_error, "
            "vdad.sweep, vdad.baselines; "
            "heavy = [m for m in ('pyrender', 'OpenGL', 'mujoco', 'pinocchio', 'trimesh', "
            "'matplotlib', 'joblib', 'dask', 'distributed') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
