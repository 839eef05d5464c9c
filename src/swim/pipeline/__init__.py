"""The orchestrator and its stages: :func:`render` wires scene -> optical volume -> solar and diffuse fields (the
kernel tables) -> camera rays -> march -> image, each stage a function between xarray and dataclass values
(docs/architecture.md, "A render").

========================== ============================================================================
module                     holds
========================== ============================================================================
``chain``                  :func:`render`: the stages in order
``arguments``              the arguments' checks, the sun, the background aerosol, the exposure
``caches``                 what the renders of a process share (:data:`STATE`) and the scenes' digests
``scene_stage``            the scene cropped, coarsened and digested; its optical volume; the camera placed
``tables``                 the kernel tables of a scene, sun and atmosphere
``sun_disk``               the sun's disk and the clouds' aureole
``image``                  the colour stage and the image's dataset
========================== ============================================================================

The writers of images and netCDF files live in :mod:`swim.io.outputs` and are importable from here too.
"""

from ..io.outputs import IMAGE_FORMATS, cf_dataset, image_format, write_image, write_netcdf, write_outputs, write_png
from ..rt.backends import IMAGE_OUTPUTS
from .arguments import RENDER_BYTES_PER_PIXEL, SPACE_VIEW_HEIGHT_M, check_render_memory, resolve_sun
from .caches import STATE
from .chain import RenderRequest, render
from .image import settings_attributes
from .scene_stage import terrain_at

__all__ = ["IMAGE_FORMATS", "IMAGE_OUTPUTS", "RENDER_BYTES_PER_PIXEL", "SPACE_VIEW_HEIGHT_M", "STATE", "RenderRequest",
           "cf_dataset", "check_render_memory", "image_format", "render", "resolve_sun", "settings_attributes",
           "terrain_at", "write_image", "write_netcdf", "write_outputs", "write_png"]
