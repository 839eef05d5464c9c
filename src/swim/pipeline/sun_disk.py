"""The sun's disk and the clouds' circumsolar aureole, added to a rendered image's radiance."""

from __future__ import annotations

import numpy as np

from ..constants import SUN_ANGULAR_RADIUS_RAD
from ..optics.cloud_phase import AUREOLE_HALF_ANGLE_RAD


def sun_disk(camera, dirs_enu, valid, sun_enu, transmittance, radius=SUN_ANGULAR_RADIUS_RAD):
    """The sun's disk: the flat indices (k,) of its pixels and their solar-relative radiance (3,), which spreads
    4 pi T_direct over the disk's pixels; no pixels where the sun is outside the image or its disk covers none.
    With another ``radius`` [rad] (at least 0.75 pixel), a circumsolar disc of that radius.

    Only its pixels are returned (rather than an image of zeros that a render added to its radiance: two passes
    over 24 MB of float64 for a 1024^2 image, docs/decisions/0009-work-around-the-march.md)."""
    none = np.zeros(0, np.int64), np.zeros(3)
    row, col = camera.pixel_of_direction(np.asarray(sun_enu)[None, :])
    if not (np.isfinite(row[0]) and np.isfinite(col[0])):
        return none
    ny, nx = dirs_enu.shape[:2]
    r = int(np.clip(np.rint(row[0]), 0, ny - 1))
    c = int(np.clip(np.rint(col[0]), 0, nx - 1))
    # the pixel's angular pitch across and along the rows: a panorama's columns close up towards the zenith
    # (cos elevation), and its rows may be further apart than its columns
    across = dirs_enu[r, c + 1] if c + 1 < nx else dirs_enu[r, c - 1]
    along = dirs_enu[r + 1, c] if r + 1 < ny else dirs_enu[r - 1, c]
    pitches = [float(np.arccos(np.clip(np.dot(dirs_enu[r, c], d), -1, 1))) if valid[r, c] else 0.0
               for d in (across, along)]
    if not all(np.isfinite(x) and x > 0 for x in pitches):
        return none
    # at least 0.75 of the larger pitch: a disk that no pixel centre falls into would lose the sun
    radius = max(radius, 0.75 * max(pitches))
    pitch = float(np.sqrt(pitches[0] * pitches[1]))  # the pixel's solid angle is about pitch^2
    # the pixels within the disk's angular radius, looked for in the window that holds them (the whole image only
    # where the disk reaches outside the camera's field): a 1024^2 image's every direction took ~5 ms a frame
    (r0, r1), (c0, c1) = _disk_window(camera, np.asarray(sun_enu, dtype=float), radius, row[0], col[0], ny, nx)
    # NaN outside the camera's pixels, where the comparison below is False
    cos_angle = dirs_enu[r0:r1, c0:c1] @ sun_enu
    rows, cols = np.nonzero(valid[r0:r1, c0:c1] & (cos_angle >= np.cos(radius)))
    if rows.size == 0:
        return none
    pixels = (rows + r0) * nx + (cols + c0)  # ascending, as flatnonzero of the whole image gives them
    return pixels, 4 * np.pi * np.asarray(transmittance, dtype=float) / (pixels.size * pitch**2)



#: Pixels added to each side of the window of :func:`_disk_window`, and the longest step [pixels] allowed between the
#: images of neighbouring directions sampled on the disk's edge: a point of the edge's image between two samples then
#: lies within the margin of one of them.
DISK_WINDOW_MARGIN = 2



#: Fewest and most directions sampled on the disk's edge (:func:`_disk_window`): about one a pixel of its image.
DISK_EDGE_DIRECTIONS = (64, 4096)



def _disk_edge_pixels(camera, sun_enu, radius, n):
    """Pixel coordinates (rows, cols) of ``n`` directions evenly spaced on the circle at ``radius`` [rad] around
    the unit vector ``sun_enu`` (ENU)."""
    axis = np.zeros(3)  # an orthonormal pair across the sun's direction, from the ENU axis least aligned with it
    axis[int(np.argmin(np.abs(sun_enu)))] = 1.0
    e1 = np.cross(sun_enu, axis)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(sun_enu, e1)
    phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return camera.pixel_of_direction(np.cos(radius) * sun_enu
                                     + np.sin(radius) * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))



def _disk_window(camera, sun_enu, radius, row, col, ny, nx):
    """Rows [r0, r1) and columns [c0, c1) of the image that hold every pixel whose direction lies within ``radius``
    [rad] of the unit vector ``sun_enu`` (ENU), whose pixel is (``row``, ``col``).

    A camera's projection maps the disk onto the region that its edge's image bounds, so the box of that curve holds
    every such pixel. The curve is sampled at about one direction a pixel (:data:`DISK_EDGE_DIRECTIONS`) and the
    samples' box widened by :data:`DISK_WINDOW_MARGIN` pixels. The whole image where that does not hold: an edge
    direction not imaged (the disk reaches outside the field of view), a step between neighbouring samples longer
    than the margin (a panorama's seam or pole inside the disk, where the curve is not closed in the image; a disk
    too big for the most samples), or a sun that is not a unit vector."""
    whole = (0, ny), (0, nx)
    norm = float(np.linalg.norm(sun_enu))
    if not (np.isfinite(norm) and abs(norm - 1.0) <= 1e-6 and np.isfinite(row) and np.isfinite(col)):
        return whole
    fewest, most = DISK_EDGE_DIRECTIONS
    rows, cols = _disk_edge_pixels(camera, sun_enu, radius, fewest)
    if not (np.all(np.isfinite(rows)) and np.all(np.isfinite(cols))):
        return whole
    # about one sample a pixel of the edge's image: its length from the first samples' mean distance to the centre
    n = int(np.clip(np.ceil(2 * np.pi * np.mean(np.hypot(rows - row, cols - col))), fewest, most))
    if n > fewest:
        rows, cols = _disk_edge_pixels(camera, sun_enu, radius, n)
        if not (np.all(np.isfinite(rows)) and np.all(np.isfinite(cols))):
            return whole
    m = DISK_WINDOW_MARGIN
    if np.max(np.hypot(np.diff(rows, append=rows[0]), np.diff(cols, append=cols[0]))) > m:
        return whole
    r0, r1 = max(int(np.floor(min(rows.min(), row))) - m, 0), min(int(np.ceil(max(rows.max(), row))) + m + 1, ny)
    c0, c1 = max(int(np.floor(min(cols.min(), col))) - m, 0), min(int(np.ceil(max(cols.max(), col))) + m + 1, nx)
    return (r0, max(r1, r0)), (c0, max(c1, c0))



def with_the_sun(planes, sun_out, cam, dirs_enu, valid, sun_enu_observer, aureole):
    """The image's radiance (3, ny, nx) with the sun's disk added, and with ``aureole`` (the 3-D cloud scattering)
    the circumsolar aureole of the clouds' forward peak, added to ``planes["radiance_cloud"]`` too (in place).
    ``planes``' ``radiance`` is taken out of it; ``sun_out`` holds the sun's ray's outputs. Returns the radiance, the
    flat indices of the pixels that changed, and the direct and circumsolar transmittances (3,) [-]."""
    t_direct = np.exp(-(sun_out["tau_clear"] + sun_out["tau_hydrometeor"]))
    if sun_out["surface"]:
        t_direct = np.zeros(3)
    disk_pixels, disk_radiance = sun_disk(cam, dirs_enu, valid, sun_enu_observer, t_direct)
    radiance = planes.pop("radiance")  # (3, ny, nx) float32
    t_aureole = np.zeros(3)
    recoloured = disk_pixels
    if aureole and not sun_out["surface"]:
        # the forward peak's narrow part, delivered about the sun (swim.optics.cloud_phase.split_phase_function)
        t_aureole = np.maximum(np.exp(-(sun_out["tau_clear"] + sun_out["tau_narrow"])) - t_direct, 0.0)
        aureole_pixels, aureole_radiance = sun_disk(cam, dirs_enu, valid, sun_enu_observer, t_aureole,
                                                     radius=AUREOLE_HALF_ANGLE_RAD)
        if aureole_pixels.size:
            for plane in (radiance, planes["radiance_cloud"]):
                flat = plane.reshape(3, -1)
                flat[:, aureole_pixels] = flat[:, aureole_pixels] + aureole_radiance[:, None]
            recoloured = np.union1d(disk_pixels, aureole_pixels)
    if disk_pixels.size:  # the disk added in float64, rounded once to the output's float32
        flat = radiance.reshape(3, -1)
        flat[:, disk_pixels] = flat[:, disk_pixels] + disk_radiance[:, None]
        radiance = flat.reshape(radiance.shape)
    return radiance, recoloured, t_direct, t_aureole

