"""Batched eigenvalues of small symmetric matrices against LAPACK (``numpy.linalg.eigvalsh``,
one matrix at a time): the closed-form 3 x 3 path of ``symmetric_eigenvalues`` and the classes
and critical factors built on it."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from stiffness.batch import kernels as batch

finite = st.floats(min_value=-1e8, max_value=1e8, allow_nan=False, allow_infinity=False)


def _from_spectrum(values: np.ndarray, seed: int) -> np.ndarray:
    """Symmetric 3 x 3 matrices with eigenvalues ``values`` (m, 3) and random eigenvectors."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.standard_normal((values.shape[0], 3, 3)))
    a = q @ (values[..., None] * np.swapaxes(q, -1, -2))
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def _assert_like_lapack(a: np.ndarray) -> None:
    got = batch.symmetric_eigenvalues(a)
    ref = np.array([np.linalg.eigvalsh(m) for m in a])
    scale = np.abs(ref).max(axis=-1, keepdims=True)
    np.testing.assert_array_less(np.abs(got - ref), 1e-10 * np.abs(ref) + 1e-14 * scale + 1e-300)


@given(arrays(np.float64, (16, 3, 3), elements=finite))
@settings(max_examples=60)
def test_any_symmetric_3x3_like_lapack(entries):
    """Whatever the entries (zero, repeated, huge, tiny), each eigenvalue agrees with LAPACK
    to 1e-10 of itself (or 1e-14 of the largest)."""
    _assert_like_lapack(0.5 * (entries + np.swapaxes(entries, -1, -2)))


@given(st.lists(st.tuples(st.floats(1e-3, 1e8), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0),
                          st.sampled_from([0.0, 1e-14, 1e-9, 1e-5, 1e-3, 1e-2, 0.1, 1.0])),
                min_size=1, max_size=32),
       st.integers(0, 2**32 - 1))
@settings(max_examples=60)
def test_spectra_near_repeated_or_spread_like_lapack(rows, seed):
    """Spectra chosen to hurt the closed form: two eigenvalues closer than any threshold,
    eigenvalues of both signs, ratios of 1e-11 between the smallest and the largest."""
    values = np.array([[s, s * (1.0 + gap), s * b] if a > 0 else [s, s * a, s * b * 1e-3]
                       for s, a, b, gap in rows])
    _assert_like_lapack(_from_spectrum(values, seed))


def test_well_separated_spectra_exact_to_round_off():
    """On well-separated, well-conditioned spectra (where the closed form is kept) the error is
    a few hundred units of round-off of the largest eigenvalue."""
    rng = np.random.default_rng(3)
    values = np.sort(rng.uniform(1e4, 1e7, (5000, 3)) * rng.choice([-1, 1], (5000, 3)), axis=-1)
    values = values[np.all(np.abs(np.diff(np.abs(values), axis=-1)) > 0.05 * 1e7, axis=-1)]
    a = _from_spectrum(values, 4)
    got = batch.symmetric_eigenvalues(a)
    ref = np.linalg.eigvalsh(a)
    assert np.abs(got - ref).max() <= 1e-13 * np.abs(ref).max()


def test_nan_matrices_give_nan_and_leave_the_others():
    a = _from_spectrum(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 7.0]]), 0)
    a[0, 1, 2] = np.nan
    got = batch.symmetric_eigenvalues(a)
    assert np.isnan(got[0]).all()
    np.testing.assert_allclose(got[1], [4.0, 5.0, 7.0], rtol=1e-13)


def test_multiples_of_identity_and_zero():
    a = np.stack([np.eye(3) * 5.0, np.zeros((3, 3)), np.diag([2.0, 2.0, -1.0])])
    np.testing.assert_array_equal(batch.symmetric_eigenvalues(a),
                                  [[5.0, 5.0, 5.0], [0.0, 0.0, 0.0], [-1.0, 2.0, 2.0]])


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=20)
def test_classes_of_3x3_equal_one_at_a_time(seed):
    """Definiteness classes from the batched eigenvalues equal the single-matrix rule, also
    for matrices with an eigenvalue at the class tolerance."""
    from stiffness.mechanics.formulation import definiteness

    rng = np.random.default_rng(seed)
    values = rng.uniform(-1, 1, (64, 3)) * 1e5
    values[::4, 0] = 1e5 * rng.choice([1e-12, 1e-9, 1.1e-9, 0.9e-9, 0.0], 16)
    a = _from_spectrum(values, seed)
    codes = batch.definiteness_codes(eigenvalues=batch.symmetric_eigenvalues(a))
    assert list(batch.class_names(codes)) == [definiteness(m) for m in a]


@given(arrays(np.float64, st.tuples(st.integers(1, 40), st.integers(1, 3)),
              elements=st.sampled_from([0.0, -0.0, 1.0, 2.5, -3.0, 1e-300])))
@settings(max_examples=60)
def test_distinct_loop_coordinates_as_numpy_unique(values):
    """The distinct closures of a batch (first visits and the map back) are numpy.unique's
    rows, in its order."""
    from stiffness.batch.linalg import distinct_rows

    first, inverse = distinct_rows(values)
    _, first_ref, inverse_ref = np.unique(values, axis=0, return_index=True,
                                          return_inverse=True)
    np.testing.assert_array_equal(first, first_ref)
    np.testing.assert_array_equal(inverse, inverse_ref.reshape(-1))


@given(st.integers(1, 6), st.integers(1, 4), st.integers(0, 2**32 - 1))
@settings(max_examples=30)
def test_point_hessian_along_a_force_is_its_contraction(s, n, seed):
    """The projected point Hessian along F (computed contracted first, as for the closed-loop
    K_C's tree term) is F . H[S_a, S_b] of the full one, and symmetric."""
    from stiffness.batch.linalg import projected_point_hessian

    rng = np.random.default_rng(seed)
    lin, om = rng.standard_normal((3, s, 7)), rng.standard_normal((3, s, 7))
    proj, force = rng.standard_normal((s, n, 7)), rng.standard_normal(3) * 100
    full = projected_point_hessian(lin, om, proj)
    along = projected_point_hessian(lin, om, proj, along=force)
    np.testing.assert_allclose(along, np.einsum("krab,r->kab", full, force),
                               rtol=1e-12, atol=1e-12 * np.abs(full).max() * 100)
    np.testing.assert_allclose(along, np.swapaxes(along, 1, 2), rtol=0, atol=1e-12 * 100 * (
        np.abs(full).max() + 1))


@given(st.integers(4, 8), st.integers(0, 2**32 - 1), st.data())
@settings(max_examples=60, deadline=None)
def test_negligible_rows_deflated_like_lapack(n, seed, data):
    """Rows negligible in every matrix of the stack (exact zeros, or round-off below 1e-13 of
    the largest entry: a joint whose axis K_C does not see) are deflated; every eigenvalue
    stays within Weyl's bound of LAPACK's on the whole matrix."""
    rng = np.random.default_rng(seed)
    dead = np.array(data.draw(st.lists(st.booleans(), min_size=n, max_size=n)))
    live = dead[:, None] | dead[None, :]
    a = rng.standard_normal((24, n, n)) * 10.0 ** rng.uniform(-3, 6, (24, 1, 1))
    a = a + np.swapaxes(a, -1, -2)
    scale = np.abs(np.where(live, 0.0, a)).max(axis=(-2, -1), keepdims=True)
    noise = data.draw(st.sampled_from([0.0, 1e-16, 1e-14]))
    tiny = 0.5 * noise * scale * rng.uniform(-1, 1, a.shape)
    tiny = np.where(live, tiny + np.swapaxes(tiny, -1, -2), 0.0)
    a = np.where(live, tiny, a)
    got = batch.symmetric_eigenvalues(a)
    ref = np.linalg.eigvalsh(a)
    assert np.all(np.diff(got, axis=-1) >= 0)
    weyl = np.linalg.norm(tiny, axis=(-2, -1))[:, None]  # |E|_2 <= |E|_F
    bound = weyl + 1e-14 * np.abs(ref).max(axis=-1, keepdims=True) + 1e-300
    np.testing.assert_array_less(np.abs(got - ref), np.broadcast_to(bound, ref.shape))
    if dead.any():  # deflated: one exact zero per negligible row
        assert np.all(np.sum(got == 0.0, axis=-1) >= dead.sum())


def test_deflated_row_has_no_determinant_sign():
    """A K_C with a negligible row has det K_C = 0 to round-off: not 'det K_C > 0', whatever
    sign LU would give its round-off; the classes still equal the eigenvalue rule's."""
    rng = np.random.default_rng(8)
    k_c = rng.standard_normal((50, 6, 6)) * 100.0
    k_c = k_c + np.swapaxes(k_c, 1, 2)
    k_c[:, 0, :] = k_c[:, :, 0] = 3e-15 * rng.uniform(-1, 1, (50, 6))
    k_c[:, 0, 0] = 0.0
    k_theta = np.diag(rng.uniform(1e4, 1e5, 6))
    d = batch.load_definiteness(k_theta, k_c)
    assert not d.determinant_positive.any()
    np.testing.assert_array_equal(d.k_c_class, batch.definiteness_codes(k_c))
    np.testing.assert_array_equal(d.tangent_class, batch.definiteness_codes(k_theta - k_c))


@given(arrays(np.float64, (8, 3, 3), elements=st.floats(-1e3, 1e3).map(lambda x: round(x, 3))),
       st.integers(-960, 960))
@settings(max_examples=40)
def test_eigenvalues_scale_with_the_matrix_to_the_last_bit(entries, power):
    """Eigenvalues are homogeneous: a matrix scaled by a power of two (exact) has its
    eigenvalues scaled by it, bit for bit, from 2^-960 to 2^960 (without scaling first, the
    closed form's cubic terms fell into subnormals below about 1e-103 and overflowed above
    about 1e102). Entries are multiples of 1e-3, so none leaves the normal range."""
    a = 0.5 * (entries + np.swapaxes(entries, -1, -2))
    expected = np.ldexp(batch.symmetric_eigenvalues(a), power)
    np.testing.assert_array_equal(batch.symmetric_eigenvalues(np.ldexp(a, power)), expected)
