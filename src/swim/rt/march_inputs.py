"""The march's inputs from a scene: the packed volume, its occupancy classes, the ground's fields and the kernel
constants of the clear atmosphere (:func:`volume_constants`, :func:`atmosphere_constants`, :func:`kernel_constants`).

Everything here is numpy: the numba kernel reads the arrays in place, and the JAX kernel takes one device copy of
them (:mod:`swim.rt.device_copies`).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
import xarray as xr

from ..constants import BACKSCATTER_FRACTION, EARTH_RADIUS_M, GAS_OZONE_ROW, SPECIES
from ..optics.phase import G_LIQUID
from ..workers import in_blocks
from .device_copies import _buffer_identity, _owner, forget_device_copies_of
from .gas import GasTables
from .surface_margin import LIGHTING_EDGE_FADE_CELLS, extend_beyond_grid, surface_margin_cells
from .march_settings import SUNLIT_CLEAR, SUNLIT_TRANSMITTANCE, _numba_available


@dataclass(frozen=True)
class GridGeometry:
    """Geometry of the optical volume needed by the kernels (see :func:`grid_geometry`)."""

    origin: np.ndarray  # (2,) [m]
    matrix: np.ndarray  # (2, 2) [m / index]
    inverse: np.ndarray  # (2, 2) [index / m]
    z_bottom: float
    dz: float
    shape: tuple  # (nk, ny, nx)
    top: float
    affine_residual_cells: float = 0.0

    @property
    def spacing(self) -> float:
        """Horizontal grid spacing [m]: the square root of a cell's area."""
        return float(np.sqrt(abs(np.linalg.det(self.matrix))))


def grid_geometry(volume) -> GridGeometry:
    """:class:`GridGeometry` of an optical volume (:func:`swim.optics.volume.build_optical_volume`)."""
    matrix = np.asarray(volume.attrs["affine_matrix"], dtype=float).reshape(2, 2)
    nk, ny, nx = volume.variables["aerosol_extinction"].shape  # a Variable: no DataArray is made
    z_bottom = float(volume.attrs["z_bottom"])
    dz = float(volume.attrs["dz"])
    spacing = float(np.sqrt(abs(np.linalg.det(matrix))))
    return GridGeometry(np.asarray(volume.attrs["affine_origin"], dtype=float), matrix, np.linalg.inv(matrix),
                        z_bottom, dz, (nk, ny, nx), z_bottom + dz * (nk - 1),
                        float(volume.attrs.get("affine_max_residual_m", 0.0)) / spacing)


def _constant(a):
    """A kernel constant: a read-only float32 numpy copy of ``a`` (the JAX kernel takes one device copy of it,
    :func:`swim.rt.march_jax._device_constants`)."""
    out = np.array(a, dtype=np.float32, order="C")  # a C-ordered copy: the compiled kernels take one layout
    out.flags.writeable = False
    return out


def gas_column_above(profiles, spectra, dh):
    """Fraction [-] of the clear air's vertical optical depth at 546 nm that lies above each height of the gas
    tables' height grid (trapezoidal rule; 1 at the grid's first height, 0 at its top; 1 everywhere for an empty
    atmosphere).

    Parameters
    ----------
    profiles : array_like, shape (n_comp, n_gas)
        Extinction [m-1] of the components (molecules (Rayleigh), background and stratospheric aerosol) at the first
        wavelength, at heights ``dh * arange(n_gas)`` [m].
    spectra : array_like, shape (n_comp, 3)
        Each component's extinction at the three wavelengths relative to the first.
    dh : float
        Height step [m] of the grid.

    Returns
    -------
    numpy.ndarray, shape (n_gas,)
        The column above each height over the whole column [-], non-increasing.
    """
    beta = (np.asarray(profiles, dtype=float) * np.asarray(spectra, dtype=float)[:, 1:2]).sum(axis=0)
    layers = 0.5 * (beta[1:] + beta[:-1]) * float(dh)
    above = np.concatenate([np.cumsum(layers[::-1])[::-1], [0.0]])
    return above / above[0] if above[0] > 0 else np.ones_like(above)


def _ends_on_surface(state, ends_on_ground):
    """Which rays end on the ground (n,) bool: a terrain hit, or a ray still alive at the end of a segment that ends
    on the sea-level sphere (JAX or numpy arrays)."""
    return state["hit"] | (ends_on_ground & state["alive"])


def surface_fields(volume, transmittance):
    """The ground's fields packed for one bilinear lookup, (ny, nx, 11): spectral albedo (3) [-], land fraction
    [-], snow cover [-], wind speed at 10 m [m s-1], terrain gradient dh/dx, dh/dy [-], and Step 1a at the
    ground (the first level at or above the terrain): cloud transmittance T [-], terrain shadow [-] and the
    3-D aerosol's optical depth towards the sun at 550 nm [-]."""
    levels = volume["level"].values
    terrain = volume["terrain_height"].values
    k = np.clip(np.searchsorted(levels, terrain - 1e-6 * float(volume.attrs["dz"])), 0, levels.size - 1)
    jj, ii = np.indices(terrain.shape)

    def at_ground(name):
        return transmittance[name].values[k, jj, ii][..., None]

    return np.concatenate([
        volume["surface_albedo"].transpose("y", "x", "wavelength").values,
        volume["land_fraction"].values[..., None], volume["snow_cover"].values[..., None],
        volume["wind_speed_10m"].values[..., None], volume["terrain_slope"].transpose("y", "x", "component").values,
        at_ground("cloud_transmittance"), at_ground("terrain_shadow"), at_ground("aerosol_tau_sun"),
    ], axis=-1)


#: The last volume's surface properties extended beyond its grid (:func:`extended_surface`): they do not depend on
#: the sun, so a time series' frames extend them once.
_EXTENDED_PROPERTIES = {}


def extended_surface(volume, fields, outside):
    """The ground's fields (C, ny, nx) of ``volume`` (:func:`surface_fields`, channel-major, C = 11) extended beyond the
    grid (:func:`extend_beyond_grid`): the surface's properties (the first 8) smoothed along the edge and tapering to
    ``outside`` (C,) over the margin, kept for the volume; its lighting by Step 1a fading within
    :data:`LIGHTING_EDGE_FADE_CELLS`. Returns the extended fields (C, ny + 2 m, nx + 2 m) and the margin m [cells]."""
    fields = np.asarray(fields, np.float32)
    margin = surface_margin_cells(*fields.shape[1:])
    entry = _EXTENDED_PROPERTIES.get("entry")
    if entry is None or entry[0]() is not volume or entry[1] != margin:
        _EXTENDED_PROPERTIES.clear()
        properties = extend_beyond_grid(fields[:8], outside[:8], margin)
        properties.flags.writeable = False
        _EXTENDED_PROPERTIES["entry"] = entry = (weakref.ref(volume), margin, properties)
    lighting = extend_beyond_grid(fields[8:], outside[8:], margin,
                                  np.full(fields.shape[0] - 8, LIGHTING_EDGE_FADE_CELLS), smoothed=False)
    return np.concatenate([entry[2], lighting]), margin


def surface_fields_outside(fields):
    """The ground far beyond the grid (11,): the packed :func:`surface_fields` (ny, nx, 11) averaged over the grid's
    edge cells, flat, lit by the unobstructed sun (T = 1, no shadow, no 3-D aerosol); near the grid it fades
    into the edge cells' own values (:func:`surface_beyond_edge`)."""
    ring = np.concatenate([fields[0], fields[-1], fields[1:-1, 0], fields[1:-1, -1]])
    out = ring.mean(axis=0)
    out[6:8] = 0.0
    out[8:11] = (1.0, 1.0, 0.0)
    return out


#: Hydrometeor extinction [m-1] above which a cell counts as occupied (0.001 optical depth per km).
OCCUPIED_EXTINCTION = 1e-6
#: Change of the 3-D aerosol's optical depth across a cell above which the cell counts as occupied [-].
OCCUPIED_AEROSOL_CHANGE = 1e-3


def occupancy_grid(volume):
    """Where rays need fine steps, (level, y, x) int8: 1 in cells with hydrometeors, next to the terrain, or with
    a 3-D aerosol that changes by more than :data:`OCCUPIED_AEROSOL_CHANGE` in optical depth across the cell,
    dilated by one cell in every direction so that a probe between two cells still sees them
    (:func:`adaptive_step_edges`). Read-only: renders share it across suns (it depends on the volume alone)."""
    from scipy.ndimage import maximum_filter, minimum_filter

    from .occupancy_cpu import occupied_cells

    dz = float(volume.attrs["dz"])
    spacing = grid_geometry(volume).spacing
    extinction = volume["extinction"].values
    levels = np.ascontiguousarray(volume["level"].values, dtype=np.float64)
    # Only raised terrain needs the march to find it: the sea-level sphere is met analytically.
    terrain = np.asarray(volume["terrain_height"].values, dtype=np.float64)
    top = maximum_filter(terrain, size=3) if np.any(terrain > 1.0) else np.zeros_like(terrain)
    occupied = np.empty(extinction.shape[1:], bool)
    # the cloud and the terrain in one compiled pass, blocks of levels on every core (a float32 matrix-vector
    # product per cell on one thread, then two passes: 0.22 s for 400 x 400 x 60, docs/decisions/0007-scene-set-up.md)
    in_blocks(lambda k0, k1: occupied_cells(extinction, np.float32(OCCUPIED_EXTINCTION), levels, top, dz, k0, k1,
                                            occupied), occupied.shape[0])
    aerosol = volume["aerosol_extinction"].values
    if np.any(aerosol > 0):
        change = (maximum_filter(aerosol, size=3) - minimum_filter(aerosol, size=3)) * max(dz, spacing)
        occupied |= change > OCCUPIED_AEROSOL_CHANGE
    occupancy = dilated_by_one_cell(occupied).view(np.int8)
    occupancy.flags.writeable = False
    return occupancy


def step_classes(occupancy, fields, out=None):
    """The cells' classes for the step placement of one sun (:func:`grid_step_edges`), (level, y, x) int8: 1 where
    ``occupancy`` (:func:`occupancy_grid`) is occupied, :data:`SUNLIT_CLEAR` (-1) in sunlit clear air, 0 in the other
    empty cells.

    A cell is sunlit clear air where it is not occupied and the direct sun reaches it and every cell next to it (the
    3 x 3 x 3 cube around it) with a transmittance of at least :data:`SUNLIT_TRANSMITTANCE`: Step 1a's cloud
    transmittance times the terrain's shadow times, with a 3-D aerosol, e^-(its sun-ward optical depth). There the
    clear sky's source (Eq. 3, Albers et al. 2020, doi:10.5194/amt-13-3235-2020) varies with height alone, through
    the smooth profiles of the gas and the background aerosol, and Eq. 12's cloud term is zero, so a ray needs few
    steps (:attr:`MarchSettings.sunlit_steps`); in the empty cells of a cloud's or the terrain's shadow the source
    changes across the shadow's edge, and they keep the empty cells' steps.

    Parameters
    ----------
    occupancy : numpy.ndarray
        Shape (level, y, x) int8: :func:`occupancy_grid` (> 0: occupied).
    fields : mapping
        Step 1a's fields (level, y, x) [-] by name: ``cloud_transmittance`` and ``terrain_shadow``, and
        ``aerosol_tau_sun`` where the volume has a 3-D aerosol (absent: none).
    out : numpy.ndarray, optional
        Shape (level, y, x) int8, written in place (an earlier sun's classes; its device copies are dropped).

    Returns
    -------
    numpy.ndarray
        Shape (level, y, x) int8, read-only: ``out`` where given.

    Raises
    ------
    ValueError
        If a field's or ``out``'s shape is not ``occupancy``'s.
    """
    from .occupancy_cpu import classify_cells, unlit_nodes

    cloud, shadow = (np.asarray(fields[name]) for name in ("cloud_transmittance", "terrain_shadow"))
    aerosol = fields.get("aerosol_tau_sun")
    has_aerosol = aerosol is not None
    aerosol = np.asarray(aerosol) if has_aerosol else np.zeros((1, 1, 1), np.float32)
    arrays = [cloud, shadow] + ([aerosol] if has_aerosol else []) + ([out] if out is not None else [])
    if any(a.shape != occupancy.shape for a in arrays):
        raise ValueError(f"step_classes: fields and out must have the occupancy's shape {occupancy.shape}, got "
                         f"{[a.shape for a in arrays]}")
    unlit = np.empty(occupancy.shape, bool)
    in_blocks(lambda k0, k1: unlit_nodes(cloud, shadow, aerosol, has_aerosol, SUNLIT_TRANSMITTANCE, k0, k1, unlit),
              unlit.shape[0])
    unlit = dilated_by_one_cell(unlit)  # a cell is sunlit only where every cell next to it is
    if out is None:
        out = np.empty(occupancy.shape, np.int8)
    else:
        forget_device_copies_of(out)
        out.flags.writeable = True
    in_blocks(lambda k0, k1: classify_cells(occupancy, unlit, np.int8(SUNLIT_CLEAR), k0, k1, out), out.shape[0])
    out.flags.writeable = False
    return out


def dilated_by_one_cell(mask):
    """A boolean array with every cell next to a True cell (a 3 x 3 x ... cube around it) set: what
    ``scipy.ndimage.maximum_filter(mask, size=3)`` gives, by one shifted ``|=`` per side and axis (bytes, in
    place: 0.03 s against scipy's 0.18 s for 160 x 400 x 400; docs/decisions/0007-scene-set-up.md); a 3-D mask (a
    grid's) in two compiled passes on every core where numba is installed (:func:`swim.rt.occupancy_cpu.dilate_cells`,
    docs/decisions/0006-gpu-kernels.md).

    Parameters
    ----------
    mask : numpy.ndarray
        Bool, any shape.

    Returns
    -------
    numpy.ndarray
        Bool, the shape of ``mask`` (a new array).
    """
    if np.ndim(mask) == 3 and _numba_available():  # a grid's: compiled, on every core (swim.rt.occupancy_cpu)
        from .occupancy_cpu import dilate_cells

        return dilate_cells(mask)
    out = np.array(mask, dtype=bool, copy=True)
    for axis in range(out.ndim):
        if out.shape[axis] < 2:
            continue
        before = out.copy()
        lower = [slice(None)] * out.ndim
        upper = [slice(None)] * out.ndim
        lower[axis], upper[axis] = slice(None, -1), slice(1, None)
        out[tuple(upper)] |= before[tuple(lower)]
        out[tuple(lower)] |= before[tuple(upper)]
    return out


def aerosol_column_optical_depth(volume):
    """Column optical depth at 550 nm of the optical volume's 3-D aerosol (y, x) [-] (sum over its levels)."""
    aer = volume["aerosol_extinction"]
    column = aer.values.sum(axis=0) * float(volume.attrs["dz"])  # numpy: no NaN-skipping copy of the volume
    return xr.DataArray(column, coords={d: aer.coords[d] for d in ("y", "x") if d in aer.coords}, dims=("y", "x"),
                        name="aerosol_column_optical_depth")


#: The variables of :func:`swim.rt.solar.solar_transmittance` that :func:`volume_constants` reads.
KERNEL_STEP1A_VARIABLES = ("aerosol_tau_sun", "cloud_transmittance", "terrain_shadow")
#: Constants of :func:`kernel_constants` kept as numpy arrays: the packed volume (the biggest array of a render)
#: and the step classes of the sun (:func:`step_classes`, under the name "occupancy"), which only the step loop reads.
#: The numba kernel reads them in place; the JAX kernel gets one device copy (:func:`_device_constants`), so a CPU
#: render does not hold the volume twice.
HOST_CONSTANTS = ("volume", "occupancy")


def kernel_constants(volume, transmittance, gas: GasTables, sun_direction_scene, radius=EARTH_RADIUS_M):
    """Arrays and scalars shared by all chunks of a render: :func:`volume_constants` and
    :func:`atmosphere_constants` in one dict."""
    return {**volume_constants(volume, transmittance), **atmosphere_constants(gas, sun_direction_scene, radius)}


def packed_aerosol_3d(n_channels, n_species) -> bool:
    """Whether a packed volume of ``n_channels`` channels and ``n_species`` packed species holds the 3-D aerosol's
    two channels.

    The packed volume's layout (:func:`pack_volume`): the extinctions of the species that are not zero everywhere
    (:func:`packed_species`, in the order of :data:`swim.constants.SPECIES`), the 3-D aerosol's extinction and its
    optical depth towards the sun (550 nm), Step 1a's cloud transmittance T, the terrain shadow (last). The terrain
    shadow cuts the direct beam only; the skylight under a cloud is dimmed by T alone. Species that are zero
    everywhere and, without a 3-D aerosol, its two channels are left out: RICO's liquid-only cumulus packs 3
    channels instead of 7 (18.5 -> 7.9 MB), and a march through it is 6-16 % faster for it
    (docs/decisions/0007-scene-set-up.md)."""
    return n_channels == n_species + 4


def packed_species(volume) -> tuple[int, ...]:
    """The species of an optical volume whose extinction is not zero everywhere: the species channels of
    :func:`pack_volume`.

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume (:func:`swim.optics.volume.build_optical_volume`): ``extinction`` (species, level, y, x)
        [m-1] over a ``species`` coordinate of names of :data:`swim.constants.SPECIES`, in that order (after
        :func:`share_packed_channels`, only the packed ones).

    Returns
    -------
    tuple of int
        Indices into :data:`swim.constants.SPECIES`, increasing.

    Raises
    ------
    ValueError
        If the ``species`` coordinate names a species not in :data:`swim.constants.SPECIES` or is out of its order.
    """
    names = [str(name) for name in volume["species"].values]
    unknown = [name for name in names if name not in SPECIES]
    if unknown:
        raise ValueError(f"optical volume: unknown species {unknown}; expected names of {SPECIES}")
    index = [SPECIES.index(name) for name in names]
    if index != sorted(set(index)):
        raise ValueError(f"optical volume: species {names} are not in the order of {SPECIES}")
    extinction = volume["extinction"].values
    nk = extinction.shape[1]
    level_bytes = int(np.prod(extinction.shape[2:])) * extinction.itemsize  # (no species at all: a clear sky)
    step = max(1, (4 << 20) // max(level_bytes, 1))  # ~4 MB of levels at a time: a cloud ends the scan

    def any_nonzero(n):
        return any(np.any(extinction[n, k0:k0 + step]) for k0 in range(0, nk, step))

    return tuple(s for n, s in enumerate(index) if any_nonzero(n))


def species_matrix(species) -> np.ndarray:
    """(len(species), len(SPECIES)) float32 one-hot rows: the packed species' optical depths (n, p) times it are
    those of all :data:`swim.constants.SPECIES` (n, 5), 0 for the species not packed (exactly: x * 1 + 0)."""
    matrix = np.zeros((len(species), len(SPECIES)), np.float32)
    matrix[np.arange(len(species)), list(species)] = 1.0
    return matrix


def pack_volume(volume, species=None):
    """The packed volume of :func:`volume_constants`, (level, y, x, channel) float32, with the grid's own channels
    filled: the extinctions of ``species`` and, where the volume has a 3-D aerosol, its extinction. Step 1a's
    channels (one sun) are left for :func:`volume_constants` to fill (their values are undefined until then).

    A render packs the grid before Step 1a and then lets the optical volume share the packed channels
    (:func:`share_packed_channels`), so the volume's own extinctions are freed before Step 1a's fields are made
    (docs/performance.md, "Memory"). Channels: the extinctions of ``species`` (indices into
    :data:`swim.constants.SPECIES`; default :func:`packed_species`, those not zero everywhere: a march through
    fewer channels reads fewer cache lines), then with a 3-D aerosol its extinction and ``aerosol_tau_sun``, then
    ``cloud_transmittance`` and ``terrain_shadow`` (``len(species) + 4`` channels with the aerosol, two fewer
    without: its channels would be zeros)."""
    if species is None:
        species = packed_species(volume)
    names = [str(name) for name in volume["species"].values]
    extinction = volume["extinction"].values
    aerosol = volume["aerosol_extinction"].values
    grid = [extinction[names.index(SPECIES[s])] for s in species]
    with_aerosol = bool(np.any(aerosol))
    if with_aerosol:
        grid.append(aerosol)
    n_channels = len(species) + (4 if with_aerosol else 2)
    packed = np.empty(extinction.shape[1:] + (n_channels,), np.float32)

    _fill_channels(packed, dict(enumerate(grid)))
    return packed


def _fill_channels(packed, values):
    """``packed[..., c] = value`` for each channel c and its ``value`` (level, y, x) of the dict ``values``, on every
    core: level by level, each level's channels one after the other while its cache lines are in the caches (0.056 s
    for the 400 x 400 x 60 scene's grid, 0.136 s channel by channel; docs/decisions/0007-scene-set-up.md). A transpose
    and a concatenate would each copy the whole volume."""
    def fill(k0, k1):
        for k in range(k0, k1):
            for c, value in values.items():
                packed[k, ..., c] = value[k]

    in_blocks(fill, packed.shape[0])


def shared_packed_volume(volume, species):
    """The packed volume that an optical volume's extinctions are views of (:func:`share_packed_channels`), so that
    a new sun refills its Step 1a channels in place (:func:`volume_constants`) instead of packing the grid again.

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume (:func:`swim.optics.volume.build_optical_volume`).
    species : tuple of int
        The species packed (indices into :data:`swim.constants.SPECIES`, :func:`packed_species`).

    Returns
    -------
    numpy.ndarray or None
        Shape (level, y, x, channel) float32: the packed volume whose first ``len(species)`` channels (and, with a
        3-D aerosol, the next) the volume's ``extinction`` (and ``aerosol_extinction``) are views of; None where
        they are not (a volume not yet shared, or shared with another layout), and the caller packs it anew.

    A new sun's repacking copied the whole grid (0.7 GB for the 400 x 400 x 60 scene's 160 levels and 7 channels,
    0.25-1.5 s on this project's 2 cores) and held two packed volumes at once (docs/decisions/0006-gpu-kernels.md).
    """
    n = len(species)
    channels = volume["extinction"].values
    packed = _owner(channels)
    if not (isinstance(packed, np.ndarray) and packed.ndim == 4 and packed.dtype == np.float32
            and packed.shape[-1] in (n + 2, n + 4) and channels.shape == (n,) + packed.shape[:-1]):
        return None
    # each view and the packed channels it must be: the same memory, shape and strides
    views = [(channels, np.moveaxis(packed[..., :n], -1, 0))]
    if packed_aerosol_3d(packed.shape[-1], n):
        views.append((volume["aerosol_extinction"].values, packed[..., n]))
    if any(_buffer_identity(view) != _buffer_identity(expected) for view, expected in views):
        return None
    return packed


def step1a_channel_names(aerosol_3d) -> tuple:
    """The packed volume's Step 1a channels by name, in their order (the last channels): :data:`KERNEL_STEP1A_VARIABLES`,
    without ``aerosol_tau_sun`` where the volume has no 3-D aerosol (:func:`packed_aerosol_3d`)."""
    return KERNEL_STEP1A_VARIABLES if aerosol_3d else KERNEL_STEP1A_VARIABLES[1:]


def step1a_channel_views(packed, species):
    """The packed volume's Step 1a channels (:data:`KERNEL_STEP1A_VARIABLES`, the 3-D aerosol's only where it is
    packed) as writeable views (level, y, x) by variable name, for :func:`swim.rt.solar.solar_transmittance` to write
    a new sun's fields into (its ``out``); :func:`volume_constants` then finds them in place and copies nothing.

    Parameters
    ----------
    packed : numpy.ndarray
        Shape (level, y, x, channel) float32: a packed volume that this process owns (:func:`pack_volume`,
        :func:`shared_packed_volume`); its device copies are dropped (its values are about to change) and it is made
        writeable until :func:`volume_constants` has filled it.
    species : tuple of int
        The species packed (indices into :data:`swim.constants.SPECIES`, :func:`packed_species`).

    Returns
    -------
    dict of str to numpy.ndarray
        ``aerosol_tau_sun`` (with a 3-D aerosol), ``cloud_transmittance`` and ``terrain_shadow``.

    The fields were made whole (~100 MB each at 400 x 400 x 160, all held until the copy) and then copied into the
    channels: one compiled pass instead takes 0.04-0.08 s off a new sun's 0.63-0.68 s for the 400 x 400 x 60 scene
    (docs/decisions/0007-scene-set-up.md)."""
    aerosol_3d = packed_aerosol_3d(packed.shape[-1], len(species))
    names = step1a_channel_names(aerosol_3d)
    first = packed.shape[-1] - len(names)
    forget_device_copies_of(packed)
    packed.flags.writeable = True
    return {name: packed[..., first + c] for c, name in enumerate(names)}


def volume_constants(volume, transmittance, occupancy=None, packed=None, species=None, classes=None):
    """The kernel constants of the grid and Step 1a (one sun), the big ones: the packed volume (level, y, x,
    channel) and the sun's step classes (level, y, x; :func:`step_classes`) as read-only numpy arrays
    (:data:`HOST_CONSTANTS`), the terrain, the ground's fields and the grid's index map as device arrays.

    ``transmittance`` needs the :data:`KERNEL_STEP1A_VARIABLES` of :func:`swim.rt.solar.solar_transmittance`;
    it is not referenced by the result, so a caller that keeps only this frees Step 1a's fields. ``occupancy``:
    the volume's :func:`occupancy_grid` (read-only), which does not depend on the sun, where the caller keeps it
    from an earlier sun; default: computed here. ``packed``: the volume's :func:`pack_volume`, whose Step 1a
    channels are filled here (in place; also an earlier sun's, :func:`shared_packed_volume`, whose device copies
    are then dropped); default: packed here. Step 1a's fields that are already the packed channels (written there by
    :func:`swim.rt.solar.solar_transmittance` through :func:`step1a_channel_views`) are not copied. ``species``: the
    species packed (indices into :data:`swim.constants.SPECIES`; default :func:`packed_species`), which the result's
    ``species_matrix`` expands to all of them. ``classes``: an earlier sun's :func:`step_classes` of this grid, to
    be written in place; default: a new array. The result's ``"occupancy"`` is the step classes of this sun (the
    kernels read an occupancy grid's 1 and 0 alike)."""
    geometry = grid_geometry(volume)
    if species is None:
        species = packed_species(volume)
    if packed is None:
        packed = pack_volume(volume, species)
    aerosol_3d = packed_aerosol_3d(packed.shape[-1], len(species))
    if packed.shape[-1] != len(species) + 2 + 2 * aerosol_3d:
        raise ValueError(f"packed volume of {packed.shape[-1]} channels does not hold the species {species}")
    n_grid = packed.shape[-1] - 2 - aerosol_3d  # channels of the grid itself
    names = step1a_channel_names(aerosol_3d)
    values = [transmittance[name].values for name in names]
    if packed.shape[:-1] != values[0].shape:
        raise ValueError(f"packed volume of shape {packed.shape} does not match Step 1a's fields {values[0].shape}")

    # a packed volume filled before (an earlier sun's): its device copies hold the old channels
    forget_device_copies_of(packed)
    packed.flags.writeable = True  # read-only for the kernels and the views; owned, so this may be set again
    # the fields that are not in their channels already (step1a_channel_views)
    missing = {n_grid + c: value for c, value in enumerate(values)
               if _buffer_identity(value) != _buffer_identity(packed[..., n_grid + c])}
    if missing:
        _fill_channels(packed, missing)
    packed.flags.writeable = False
    if occupancy is None:
        occupancy = occupancy_grid(volume)
    classes = step_classes(occupancy, dict(zip(names, values)), out=classes)
    surface = surface_fields(volume, transmittance)
    outside = surface_fields_outside(surface)
    extended, margin = extended_surface(volume, np.moveaxis(surface, -1, 0), outside)
    f32 = _constant
    return {
        # host arrays (HOST_CONSTANTS): the numba kernel reads them in place; the JAX kernel gets one device copy
        "volume": packed,
        "occupancy": classes,
        "terrain": f32(volume["terrain_height"].values[None]),
        # the ground's fields with a margin beyond the grid (extended_surface), and the ground far beyond it
        "surface": f32(extended),
        "surface_margin": f32(margin),
        "surface_outside": f32(outside),
        "index_map": {key: f32(volume.attrs[key]) for key in ("index_map_centre", "index_map_scale", "index_map_coefficients",
                                                             "index_map_bounds") if key in volume.attrs},
        "z_bottom": f32(geometry.z_bottom),
        "dz": f32(geometry.dz),
        "aerosol_column": f32(aerosol_column_optical_depth(volume).values[None]),
        "species_matrix": f32(species_matrix(species)),
    }


def share_packed_channels(volume, packed, species=None):
    """Point the optical volume's ``extinction`` (species, level, y, x) and, where packed, ``aerosol_extinction``
    (level, y, x) at their channels of a packed volume (:func:`pack_volume`, or the ``"volume"`` of
    :func:`volume_constants`) as read-only views, freeing the volume's own copies: a render then holds the grid's
    extinctions once (docs/performance.md, "Memory").

    The values are unchanged (the packed channels are copies of them), but the ``species`` coordinate then names
    only the packed ones (``species``, indices into :data:`swim.constants.SPECIES`; default
    :func:`packed_species`): the others were zero everywhere. A later Step 1a (a new sun) reads the views, and the
    next :func:`pack_volume` copies them into its own packed volume, which may then be shared in turn. Modifies
    ``volume`` in place and returns it."""
    if species is None:
        species = packed_species(volume)
    n_species = len(species)
    channels = np.moveaxis(packed[..., :n_species], -1, 0).view()
    channels.flags.writeable = False
    extinction, coordinate = volume["extinction"], volume["species"]
    # the species dimension changes size: the variable and its coordinate go first (the same Dataset object)
    del volume["extinction"]
    del volume["species"]
    volume["extinction"] = xr.Variable(extinction.dims, channels, extinction.attrs)
    volume.coords["species"] = xr.Variable("species", np.array([SPECIES[s] for s in species], coordinate.dtype),
                                           coordinate.attrs)
    if packed_aerosol_3d(packed.shape[-1], n_species):
        aerosol = packed[..., n_species].view()
        aerosol.flags.writeable = False
        volume["aerosol_extinction"] = volume["aerosol_extinction"].copy(data=aerosol)
    return volume


def atmosphere_constants(gas: GasTables, sun_direction_scene, radius=EARTH_RADIUS_M):
    """The kernel constants of the clear atmosphere (:mod:`swim.rt.gas` tables), the sun and the hydrometeor
    optics: small device arrays and scalars. ``beta_gas`` (5, n_gas) is the clear air's height table: the
    extinction profiles [m-1] of molecules, background and stratospheric aerosol and ozone's absorption
    (row :data:`swim.constants.GAS_OZONE_ROW`, zero without ozone) at the first wavelength (their spectra in
    ``beta_gas_spectra`` (4, 3)), then the fraction of the scattering components' vertical optical depth above each
    height (:func:`gas_column_above`, row :data:`swim.constants.GAS_COLUMN_ROW`).

    Ozone adds to the extinction along every line of sight but to no scattering source (docs/rendering.md, "Ozone
    and twilight"); with ``ozone_du=0`` its row is zero and the kernels add exact zeros."""
    classes = np.asarray(gas.diffuse_horizontal_classes)  # (n_class, nu, nmu, 3)
    # Molecules, background and stratospheric aerosol and ozone: each a height profile times a spectrum, so the
    # kernel looks up 4 profiles instead of 12 columns; the spectra relative to the first wavelength.
    ozone = gas.ozone_extinction
    components = [np.asarray(b, dtype=float)
                  for b in (gas.beta_rayleigh, gas.beta_aerosol, gas.beta_stratospheric, ozone)]
    spectra = np.ones((len(components), 3))
    for c, b in enumerate(components):
        if b[:, 0].sum() > 0:
            spectra[c] = b.sum(axis=0) / b[:, 0].sum()
            if not np.allclose(b, b[:, :1] * spectra[c][None, :], rtol=1e-5, atol=1e-30):
                raise ValueError("clear-atmosphere extinction must be a height profile times a spectrum")
    sun = np.asarray(sun_direction_scene, dtype=float)
    profiles = np.stack([b[:, 0] for b in components])
    # the rows of the height table: the four profiles, then the column of the three scattering ones above each height
    # (GAS_COLUMN_ROW: the step counts after the grid follow the clear-sky source, which ozone does not scatter)
    height_table = np.concatenate([profiles, gas_column_above(profiles[:GAS_OZONE_ROW], spectra[:GAS_OZONE_ROW],
                                                              gas.dh)[None]])
    f32 = _constant
    return {
        "radius": f32(radius),
        "sun": f32(sun),
        "mu0": f32(sun[2]),
        "dh": f32(gas.dh),
        "top": f32(gas.top_m),
        "beta_gas": f32(height_table),
        "beta_gas_spectra": f32(spectra),
        "sky": f32(np.moveaxis(np.concatenate([gas.sun_transmittance, gas.diffuse_horizontal], axis=-1), -1, 0)),
        "ms_source": f32(np.stack([t.source for t in gas.diffuse_sources])),
        "diffuse_classes": f32(np.moveaxis(classes, -1, 0).reshape(3, -1, classes.shape[2])),
        "class_aod": f32(gas.aerosol_class_aod),
        "angstrom": f32(gas.angstrom_factor),
        "aerosol_ssa": f32(gas.aerosol.ssa),
        "stratospheric_ssa": f32(gas.aerosol.stratospheric.ssa),
        "g_liquid": f32(G_LIQUID),
        "backscatter": f32([BACKSCATTER_FRACTION[s] for s in SPECIES]),
    }
