"""The generated octant sweep (swim.rt.ordinates_cpu.octant_sweep) against a plain loop-by-loop statement of the
same step scheme, over quadrature sizes, octants, terrain, the grid's sides, the ground and the column output."""

import math

import numpy as np
import pytest

from swim.rt import ordinates_cpu
from swim.rt.ordinates import harmonic_degrees, make_quadrature, real_spherical_harmonics


def _reference_sweep(sx, sy, sz, nz, ny, nx, beta, sigma, beam, phi_in, phi_out, harmonics, beam_phase, degree,
                     weights, ax, ay, az, inv_dz, side_x, side_y, ground_level, ground_emission, ground_flux,
                     with_beam, column_radiance):
    """The step scheme written out cell by cell, direction by direction (float64, no work arrays shared)."""
    nq, nm = harmonics.shape
    n_l = beam_phase.shape[1]
    out_z = {}  # (column, q, c) -> radiance leaving the previous level
    for col in range(ny * nx):
        for q in range(nq):
            for c in range(3):
                out_z[col, q, c] = ground_emission[col, c] if sz > 0 else 0.0
    for kk in range(nz):
        k = kk if sz > 0 else nz - 1 - kk
        out_y = {(i, q, c): side_y[k, 3 * q + c] for i in range(nx) for q in range(nq) for c in range(3)}
        for jj in range(ny):
            j = jj if sy > 0 else ny - 1 - jj
            out_x = {(q, c): side_x[k, 3 * q + c] for q in range(nq) for c in range(3)}
            for ii in range(nx):
                i = ii if sx > 0 else nx - 1 - ii
                col, cell = j * nx + i, k * ny * nx + j * nx + i
                if k < ground_level[col]:
                    for q in range(nq):
                        for c in range(3):
                            out_x[q, c] = out_y[i, q, c] = 0.0
                            out_z[col, q, c] = ground_emission[col, c] if sz > 0 else 0.0
                    continue
                for q in range(nq):
                    a = (ax[q], ay[q], az[q] * inv_dz[k])
                    for c in range(3):
                        s = sum(harmonics[q, m] * sigma[cell, c * n_l + degree[m]] * phi_in[cell, c * nm + m]
                                for m in range(nm))
                        if with_beam:
                            s += sum(beam_phase[q, l] * beam[cell, c] * sigma[cell, c * n_l + l] for l in range(n_l))
                        inflow = a[0] * out_x[q, c] + a[1] * out_y[i, q, c] + a[2] * out_z[col, q, c]
                        # I = (S + sum a_d I_in,d) / (beta + sum a_d) along a path of optical length x, exactly:
                        # the mean and outgoing radiance of a cell with a uniform source and inflow
                        x = beta[cell, c] / sum(a)
                        jsrc = s / beta[cell, c] if beta[cell, c] > 0 else 0.0
                        inflow /= sum(a)
                        if x > 1e-6:
                            e = math.exp(-x)
                            mean = jsrc + (inflow - jsrc) * (1 - e) / x
                            out = jsrc + (inflow - jsrc) * e
                        else:  # a transparent cell: the source's path integral, half of it at the mean
                            mean, out = inflow + 0.5 * s / sum(a), inflow + s / sum(a)
                        out_x[q, c] = out_y[i, q, c] = out_z[col, q, c] = out
                        for m in range(nm):
                            phi_out[cell, c * nm + m] += weights[q] * harmonics[q, m] * mean
                        if sz < 0 and k == ground_level[col]:
                            ground_flux[col, c] += weights[q] * az[q] * out
                        if column_radiance.shape[0] == nz and col == 0:
                            column_radiance[k, 3 * q + c] = mean


def _case(n_polar, n_azimuth, max_degree, seed=3, shape=(5, 3, 4)):
    rng = np.random.default_rng(seed)
    quad = make_quadrature(n_polar, n_azimuth, max_degree)
    nz, ny, nx = shape
    n_cells, nm, n_l = nz * ny * nx, (max_degree + 1) ** 2, max_degree + 1
    nq = quad.per_octant
    degree = harmonic_degrees(max_degree).astype(np.int64)
    sun_harm = real_spherical_harmonics(-np.array([0.3, 0.2, 0.93]) / np.linalg.norm([0.3, 0.2, 0.93]), max_degree)
    beam_phase = np.zeros((quad.n_directions, n_l))
    for m, l in enumerate(degree):
        beam_phase[:, l] += quad.harmonics[:, m] * sun_harm[m]
    beta = rng.uniform(0.0, 0.02, (n_cells, 3)).astype(np.float32)
    beta[::7] = 0.0  # transparent cells (the series branch)
    beta[3::11] *= 300.0  # optically thick cells
    return {
        "quad": quad, "shape": shape, "degree": degree, "beam_phase": beam_phase, "beta": beta,
        "sigma": (rng.uniform(0.0, 1.0, (n_cells, 3 * n_l)) * np.repeat(beta, n_l, axis=1)).astype(np.float32),
        "beam": rng.uniform(0.0, 1.0, (n_cells, 3)).astype(np.float32),
        "phi_in": rng.uniform(0.0, 1.0, (n_cells, 3 * nm)).astype(np.float32),
        "side": rng.uniform(0.0, 0.1, (nz, 3 * nq)).astype(np.float32),
        "ground_level": np.array([0, 1, 0, 2, 0, 0, 1, 0, 0, 0, 3, 0][:ny * nx], np.int64),
        "emission": rng.uniform(0.0, 0.2, (ny * nx, 3)).astype(np.float32),
        "inv_dz": 1.0 / rng.uniform(50.0, 200.0, nz),
    }


# the largest quadrature's kernel takes ~15 s to compile: the full tier
@pytest.mark.parametrize("n_polar, n_azimuth, max_degree",
                         [(2, 8, 2), (1, 4, 0), pytest.param(3, 12, 3, marks=pytest.mark.full)])
@pytest.mark.parametrize("octant", [0, 5])
@pytest.mark.parametrize("with_beam", [True, False])
def test_the_generated_sweep_is_the_step_scheme(n_polar, n_azimuth, max_degree, octant, with_beam):
    d = _case(n_polar, n_azimuth, max_degree)
    quad, (nz, ny, nx) = d["quad"], d["shape"]
    nq, nm, n_l = quad.per_octant, (max_degree + 1) ** 2, max_degree + 1
    s = slice(octant * nq, (octant + 1) * nq)
    sx, sy, sz = (int(v) for v in quad.octants[octant])
    dirs = quad.directions[s]
    ax, ay, az = np.abs(dirs[:, 0]) / 120.0, np.abs(dirs[:, 1]) / 90.0, np.abs(dirs[:, 2])
    common = (d["beta"], d["sigma"], d["beam"], d["phi_in"])
    outputs = {}
    for name in ("generated", "reference"):
        phi_out = np.full((nz * ny * nx, 3 * nm), 0.25, np.float32 if name == "generated" else np.float64)
        flux = np.zeros((ny * nx, 3))
        column = np.zeros((nz, 3 * nq), np.float32 if name == "generated" else np.float64)
        if name == "generated":
            kernel = ordinates_cpu.octant_sweep(nq, nm, n_l, tuple(d["degree"]))
            kernel(sx, sy, sz, nz, ny, nx, *common, phi_out, quad.harmonics[s], d["beam_phase"][s], quad.weights[s],
                   ax, ay, az, d["inv_dz"], d["side"], d["side"][::-1].copy(), d["ground_level"], d["emission"], flux,
                   with_beam, np.zeros((ny * nx, 3 * nq), np.float32), np.zeros((nx, 3 * nq), np.float32), column)
        else:
            _reference_sweep(sx, sy, sz, nz, ny, nx, *common, phi_out, quad.harmonics[s], d["beam_phase"][s],
                             d["degree"], quad.weights[s], ax, ay, az, d["inv_dz"], d["side"], d["side"][::-1],
                             d["ground_level"], d["emission"], flux, with_beam, column)
        outputs[name] = (phi_out, flux, column)
    for got, want in zip(outputs["generated"], outputs["reference"]):
        np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-6 * np.abs(want).max())
    assert np.any(outputs["reference"][2] != 0)  # column (0, 0) was written
    if sz < 0:
        assert np.count_nonzero(outputs["reference"][1]) >= 3 * (ny * nx - 1)  # the grounds received light


def test_inconsistent_sizes_are_refused():
    with pytest.raises(ValueError, match="inconsistent quadrature sizes"):
        ordinates_cpu.sweep_source(4, 9, 3, (0, 1, 1, 1))
    with pytest.raises(ValueError, match="inconsistent quadrature sizes"):
        ordinates_cpu.sweep_source(4, 4, 2, (0, 1, 1, 2))


def test_the_kernel_is_compiled_once_per_size():
    a = ordinates_cpu.octant_sweep(1, 1, 1, (0,))
    assert ordinates_cpu.octant_sweep(1, 1, 1, (0,)) is a
    assert ordinates_cpu.octant_sweep(1, 4, 2, (0, 1, 1, 1)) is not a


@pytest.mark.full  # compiles the sweep once more, in memory: the full tier
def test_without_a_disk_cache_the_kernel_is_compiled_from_memory(monkeypatch, tmp_path):
    source = ordinates_cpu.sweep_source(1, 1, 1, (0,))
    monkeypatch.setitem(ordinates_cpu.JIT_KERNEL, "cache", False)
    in_memory = ordinates_cpu._compile_sweep(source, "sweep_test_memory")
    monkeypatch.setitem(ordinates_cpu.JIT_KERNEL, "cache", True)
    monkeypatch.setattr(ordinates_cpu.numba.config, "CACHE_DIR", str(tmp_path))
    on_disk = ordinates_cpu._compile_sweep(source, "sweep_test_disk")
    assert (tmp_path / "generated" / "sweep_test_disk.py").read_text().endswith(source)
    results = []
    for kernel in (in_memory, on_disk):
        phi_out, flux = np.zeros((2, 3), np.float32), np.zeros((1, 3))
        kernel(1, 1, -1, 2, 1, 1, np.full((2, 3), 0.01, np.float32), np.full((2, 3), 0.005, np.float32),
               np.ones((2, 3), np.float32), np.zeros((2, 3), np.float32), phi_out, np.ones((1, 1)), np.ones((1, 1)),
               np.ones(1), np.zeros(1), np.zeros(1), np.ones(1), np.full(2, 0.01), np.zeros((2, 3), np.float32),
               np.zeros((2, 3), np.float32), np.zeros(1, np.int64), np.zeros((1, 3), np.float32), flux, True,
               np.zeros((1, 3), np.float32), np.zeros((1, 3), np.float32), np.zeros((0, 3), np.float32))
        results.append((phi_out, flux))
    np.testing.assert_array_equal(results[0][0], results[1][0])
    assert np.all(results[0][0] > 0) and np.all(results[0][1] > 0)
