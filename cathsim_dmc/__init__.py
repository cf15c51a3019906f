"""cathsim-dmc: endovascular guidewire navigation on MuJoCo and dm_control.

Importing the package selects a headless OpenGL backend when there is no display and
registers a Gymnasium id ``cathsim_dmc/{task}-{aorta}-v0`` for every suite task.
"""

from cathsim_dmc.sim import gl_backend as _gl

_gl.select_backend()

__version__ = "0.1.0"

from cathsim_dmc.core import registry as _registry  # noqa: E402  (names only: no dm_control, no MuJoCo)

_registry.register_all()
