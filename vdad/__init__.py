"""vdad: view-dependent dynamics of articulated bodies (Kim, Redon and Kim 2008).

``import vdad`` loads numpy only: renderers, MuJoCo, Pinocchio and trimesh load
when a function needs them.
"""

from .assembly import AssemblyTree
from .dynamics import forward_dynamics, inverse_dynamics, passive_forces
from .errors import (
    InputError,
    ModelError,
    RenderError,
    SimulationError,
    UnsupportedFeatureError,
    VdadError,
)
from .interop.mujoco import from_mujoco, load_mjcf
from .model import Body, Geom, Joint, Model, Pose
from .simulator import Simulator

__version__ = "0.1.0"

__all__ = [
    "AssemblyTree", "Body", "Geom", "InputError", "Joint", "Model", "ModelError", "Pose",
    "RenderError", "SimulationError", "Simulator", "UnsupportedFeatureError", "VdadError",
    "forward_dynamics", "from_mujoco", "inverse_dynamics", "load_mjcf", "passive_forces",
]
