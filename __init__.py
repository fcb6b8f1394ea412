# Extension entry point: Blender loads this file; the add-on itself lives in scratch_addon/.
from .scratch_addon import register, unregister  # noqa: F401
