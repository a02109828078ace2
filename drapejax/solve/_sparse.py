"""Projected-Newton Hessians assembled as sparse matrices and solved directly on the host.

Each term's element Hessians can be projected to positive semi-definite (eigenvalues clamped
at zero, Teran et al. 2005), so that every Newton direction is a descent direction; the sparse
system is factorised on the host (on a CPU through a named XLA FFI target, ``_host_ffi``, so
that the programs holding it can be cached; from other backends through a callback): a
supernodal Cholesky (CHOLMOD, from cvxopt) when the matrix is positive definite, which is also
the test of positive definiteness, else qdldl's LDLᵀ, SuperLU as the last fallback. The exact
Hessian is used instead wherever its Cholesky factorisation succeeds, and, optionally, where it
is not, the exact Hessian plus the smallest of a ladder of diagonal shifts that makes it so
(``sparse_solve_shifted``): there Newton converges quadratically, or nearly, while the
projected Hessian, which drops the compressive membrane curvature that folds live on,
converges only linearly. This is the fast path on CPU; the matrix-free PCG in ``_newton`` is
the device (GPU) path.
"""

from __future__ import annotations

import functools
import threading
from concurrent.futures import ThreadPoolExecutor

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import qdldl
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from cvxopt import cholmod
from cvxopt import matrix as cvx_matrix
from cvxopt import spmatrix as cvx_spmatrix
from threadpoolctl import ThreadpoolController

from ._host_ffi import host_call, target_name
from .threads import available_cpus

_BLAS = ThreadpoolController()
_WORKERS = available_cpus()
_POOL = ThreadPoolExecutor(_WORKERS, thread_name_prefix="drapejax-eigh")


def _psd_chunk(h, xp=np, absolute: bool = False):
    """Eigenvalue clamp at zero (``absolute``: eigenvalues by their magnitude) with the array
    module ``xp`` (NumPy on the host, jax.numpy on a device)."""
    w, q = xp.linalg.eigh(0.5 * (h + xp.swapaxes(h, -1, -2)))
    return (q * (xp.abs(w) if absolute else xp.maximum(w, 0.0))[..., None, :]) @ xp.swapaxes(q, -1, -2)


def _psd_host(h, absolute: bool = False):
    """Eigenvalue clamp of a batch of small matrices: one single-threaded LAPACK call per core.

    OpenBLAS's own threading on many tiny eigenproblems is 3-40x slower than one thread (it
    spins up its pool per call, worst when another process shares the cores), so BLAS is held
    to one thread and the batch is split over a Python pool instead (LAPACK releases the GIL),
    in chunks of at least 64 matrices. A non-finite matrix, or one whose eigenproblem LAPACK
    cannot converge (finite entries of extreme magnitude), comes back as NaN, so the solver reports
    a non-finite state instead of failing the whole batch.
    """
    m = h.shape[-1]
    flat = np.asarray(h, np.float64).reshape(-1, m, m)
    bad = ~np.isfinite(flat).all(axis=(1, 2))
    flat = np.where(bad[:, None, None], 0.0, flat)
    with _BLAS.limit(limits=1, user_api="blas"):
        chunks = np.array_split(flat, max(1, min(_WORKERS, len(flat) // 64)))
        parts = list(_POOL.map(functools.partial(_psd_or_nan, absolute=absolute), chunks))
    out = np.concatenate(parts)
    out[bad] = np.nan
    return out.reshape(h.shape).astype(h.dtype)


def _psd_or_nan(h, absolute: bool = False):
    """``_psd_chunk`` on the host; where LAPACK raises for the chunk, matrix by matrix, NaN for
    each one it cannot decompose."""
    try:
        return _psd_chunk(h, np, absolute)
    except np.linalg.LinAlgError:
        out = np.full_like(h, np.nan)
        for i, hi in enumerate(h):
            try:
                out[i] = _psd_chunk(hi, np, absolute)
            except np.linalg.LinAlgError:
                pass
        return out


def psd_project(h: jax.Array, absolute: bool = False) -> jax.Array:
    """Clamp the eigenvalues of a batch of symmetric matrices (..., m, m) at zero (``absolute``:
    replace each by its magnitude, Longva et al. 2023).

    On CPUs NumPy's eigh on the host instead of ``jnp.linalg.eigh``: jaxlib 0.10 splits a
    batched CPU eigh over the intra-op thread pool and waits for the pieces on a worker of that
    same pool, so two such calls scheduled at once (two energy terms) deadlock on a 2-core
    machine. On accelerators the batched eigh stays on the device.
    """
    if jax.default_backend() != "cpu":
        return _psd_chunk(h, jnp, absolute)
    return host_call(target_name("psd", absolute), functools.partial(_psd_host, absolute=absolute),
                     jax.ShapeDtypeStruct(h.shape, h.dtype), h, vmap_method="expand_dims")


def element_hessians(term, x, mesh, params, project: bool = True, exact: bool = False, absolute: bool = False):
    """One term's element stencils (e, k) and element Hessians (e, 3k, 3k).

    ``project``: PSD-project each exact element Hessian. A term with its own PSD approximation
    (``has_psd_hessian``, e.g. a Gauss–Newton form) gives that instead unless ``exact``: Newton
    steps take it (exact steps not, with ``SolverConfig.shifted_steps``), the implicit adjoint
    needs the exact Hessian. ``absolute``: project by the eigenvalues' magnitudes (``psd_project``).
    """
    with jax.ensure_compile_time_eval():  # a closed-over mesh's stencils stay constants: ``stencil_coo``
        idx, data = term.elements(mesh)
    if term.has_psd_hessian and not exact:
        return idx, _element_batch(term, x[idx], data, params, True)
    vals = _element_batch(term, x[idx], data, params, False)
    return idx, (psd_project(vals, absolute) if project else vals)


@eqx.filter_jit
def _element_batch(term, xe, data, params, psd: bool):
    """``term``'s element Hessians (its PSD approximation with ``psd``), vmapped over elements.

    A Newton step asks for each term's element Hessians several times (the exact, projected and
    absolute matrices, in every level's drop and static solve); as one jitted function, each is
    traced once per term and shape and the rest reuse that trace (tracing was most of a
    cached ``drapejax simulate``'s time)."""
    fn = term.psd_element_hessian if psd else term.element_hessian
    return jax.vmap(lambda a, d: fn(a, d, params))(xe, data)


_PAIR_ORDERS: dict = {}


def _pair_order(idx: np.ndarray):
    """Host-side map from a term's stencil entries to the vertex pairs they couple.

    For stencils ``idx`` (e, k): the positions in (e, k, k) of the entries (e, i, j) with
    ``idx[e, i] <= idx[e, j]``, sorted by vertex pair (a, b); each one's pair number; the pairs'
    3x3 block positions (rows, cols, each (9 p,), block-major); and the positions among those of
    the off-diagonal pairs' entries, whose mirrored blocks complete the symmetric matrix. Cached
    per stencil array (a few recent ones)."""
    key = (idx.shape, hash(idx.tobytes()))
    if key not in _PAIR_ORDERS:
        e, k = idx.shape
        n = int(idx.max()) + 1
        a = np.broadcast_to(idx[:, :, None], (e, k, k)).reshape(-1).astype(np.int64)
        b = np.broadcast_to(idx[:, None, :], (e, k, k)).reshape(-1).astype(np.int64)
        entry = np.flatnonzero(a <= b)
        pairs, pair = np.unique(a[entry] * n + b[entry], return_inverse=True)
        order = np.argsort(pair, kind="stable")
        pa, pb = pairs // n, pairs % n
        ij = np.arange(3)
        rows = np.broadcast_to(3 * pa[:, None, None] + ij[None, :, None], (pairs.size, 3, 3)).reshape(-1)
        cols = np.broadcast_to(3 * pb[:, None, None] + ij[None, None, :], (pairs.size, 3, 3)).reshape(-1)
        mirror = np.flatnonzero(np.repeat(pa != pb, 9))
        if len(_PAIR_ORDERS) >= 8:
            _PAIR_ORDERS.pop(next(iter(_PAIR_ORDERS)))
        _PAIR_ORDERS[key] = tuple(np.asarray(v, np.int32) for v in (entry[order], pair[order].reshape(-1), rows,
                                                                    cols, mirror))
    return _PAIR_ORDERS[key]


def stencil_coo(idx, vals):
    """(rows, cols, vals) of element matrices ``vals`` (e, 3k, 3k) over stencils ``idx`` (e, k).

    Summed per vertex pair on the device before they leave it: a pair's 3x3 block is the sum of
    its entries over every element whose stencil holds both vertices (one sorted segment sum,
    ``_pair_order``), and the lower blocks mirror the upper ones. Large stencils overlap (each
    vertex pair of the hourglass control's 2-rings lies in about ten of them), so the sums are
    several times fewer than the entries, and sending the entries to the host to be summed there
    was most of a Newton step's time (``docs/results/2026-12-05-newton-step-assembly.md``).
    Stencils that are traced (a mesh passed as an argument, not closed over) are not summed:
    their entries go to the host as they are (the sparse solve sums duplicates either way)."""
    e, k = idx.shape
    try:
        entry, pair, rows, cols, mirror = _pair_order(np.asarray(idx))
    except jax.errors.TracerArrayConversionError:
        with jax.ensure_compile_time_eval():
            dof = (3 * idx[:, :, None] + jnp.arange(3)[None, None]).reshape(e, 3 * k)
            rows = jnp.broadcast_to(dof[:, :, None], (e, 3 * k, 3 * k)).reshape(-1)
            cols = jnp.broadcast_to(dof[:, None, :], (e, 3 * k, 3 * k)).reshape(-1)
        return rows, cols, vals.reshape(-1)
    blocks = vals.reshape(e, k, 3, k, 3).transpose(0, 1, 3, 2, 4).reshape(e * k * k, 3, 3)
    summed = jax.ops.segment_sum(blocks[entry], pair, num_segments=rows.shape[0] // 9, indices_are_sorted=True)
    flat = summed.reshape(-1)
    return (np.concatenate([rows, cols[mirror]]), np.concatenate([cols, rows[mirror]]),
            jnp.concatenate([flat, flat[mirror]]))


def term_hessian_coo(term, x, mesh, params, project: bool = True, exact: bool = False, absolute: bool = False):
    """(rows, cols, vals) of one term's Hessian (see ``element_hessians``), summed per vertex
    pair (``stencil_coo``); a fixed pattern. Public as ``drapejax.solve.term_hessian_coo``: the
    experiments assemble single terms' Hessians."""
    idx, vals = element_hessians(term, x, mesh, params, project, exact, absolute)
    return stencil_coo(idx, vals)


def hessian_coo(terms, x, mesh, params, diag, project: bool = True, exact: bool = False):
    """Hessian of all terms (see ``element_hessians``) plus ``diag`` (n,) on every 3x3 block."""
    return with_diagonal([term_hessian_coo(t, x, mesh, params, project, exact) for t in terms], diag)


def with_diagonal(parts, diag):
    """Terms' (rows, cols, vals) triplets joined, plus ``diag`` (n,) on every 3x3 block.

    The positions (rows, cols) depend on the mesh alone: for a mesh closed over by the traced
    function they are computed at trace time, as constants, so that the sparse solve can bind
    its pattern there (``_host``) instead of receiving them at every call.
    """
    with jax.ensure_compile_time_eval():
        d = jnp.arange(3 * diag.shape[0])
        rows = jnp.concatenate([r for r, _, _ in parts] + [d])
        cols = jnp.concatenate([c for _, c, _ in parts] + [d])
    return rows, cols, jnp.concatenate([v for _, _, v in parts] + [jnp.repeat(diag, 3)])


def _csc(rows, cols, vals, n: int) -> sp.csc_matrix:
    """The n×n COO triplets (duplicates summed) as a float64 CSC matrix."""
    return sp.csc_matrix((np.asarray(vals, np.float64), (np.asarray(rows), np.asarray(cols))), shape=(n, n))


class _Pattern:
    """The fixed sparsity pattern of one mesh's Hessian, and its reusable factorisations.

    A Newton solve factorises matrices that differ only in their values, so the COO → CSC
    scatter map, CHOLMOD's symbolic analysis (fill-reducing ordering, supernodes) and qdldl's
    AMD ordering and elimination tree are computed once per pattern, and every later matrix
    costs a ``bincount`` and a numeric refactorisation. At 5 mm Cusick (6.5k dof, 1.85M
    triplets) the pattern reuse took a qdldl solve from 0.21 s to 0.16 s; the supernodal
    Cholesky factorises 4-5x faster than qdldl
    (``docs/results/2026-11-23-benchmarks-cpu-direct-solver.md``).
    """

    def __init__(self, rows: np.ndarray, cols: np.ndarray, n: int):
        self.rows, self.cols, self.n = rows.copy(), cols.copy(), n
        self.upper = np.flatnonzero(rows <= cols)
        key = cols[self.upper].astype(np.int64) * n + rows[self.upper]
        ukey, self.slot = np.unique(key, return_inverse=True)
        self.indices = (ukey % n).astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(ukey // n, minlength=n))]).astype(np.int32)
        self.diag = np.flatnonzero(ukey // n == ukey % n)
        self.ldlt: qdldl.Solver | None = None
        self.chol = cvx_spmatrix(cvx_matrix(np.zeros(ukey.size)), cvx_matrix(ukey % n), cvx_matrix(ukey // n), (n, n))
        self.symbolic = None
        self.lock = threading.Lock()
        self.name = target_name("pattern", n, self.rows, self.cols)

    def matches(self, rows: np.ndarray, cols: np.ndarray, n: int) -> bool:
        return (n == self.n and rows.shape == self.rows.shape and np.array_equal(rows, self.rows)
                and np.array_equal(cols, self.cols))

    def upper_data(self, vals: np.ndarray) -> np.ndarray:
        """The upper-triangle CSC values of the matrix with these triplet values."""
        return np.bincount(self.slot, weights=vals.take(self.upper), minlength=self.indices.size)

    def cholesky_solve(self, data: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
        """Solve with the Cholesky factor of the matrix with these upper CSC values, or None when
        it is not (numerically) positive definite or not finite; the caller holds ``lock``."""
        if not np.all(np.isfinite(data)):
            return None
        self.chol.V = cvx_matrix(data)
        if self.symbolic is None:
            self.symbolic = cholmod.symbolic(self.chol, uplo="U")
        try:
            cholmod.numeric(self.chol, self.symbolic)
        except ArithmeticError:
            return None
        out = cvx_matrix(np.asarray(rhs, np.float64))
        cholmod.solve(self.symbolic, out)
        out = np.asarray(out).reshape(-1)
        return out if np.all(np.isfinite(out)) else None

    def factor(self, data: np.ndarray) -> qdldl.Solver:
        """LDLᵀ of the matrix with these upper CSC values (``upper_data``); the caller holds ``lock``."""
        a = sp.csc_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))
        try:
            if self.ldlt is None:
                self.ldlt = qdldl.Solver(a, upper=True)
            else:
                self.ldlt.update(a, upper=True)
        except (ValueError, RuntimeError):
            self.ldlt = None
            raise
        return self.ldlt


_PATTERNS: list[_Pattern] = []
_PATTERNS_LOCK = threading.Lock()
_MAX_PATTERNS = 4


def _pattern(rows, cols, n: int) -> _Pattern:
    """The cached pattern of these triplet positions (most recently used kept, at most 4)."""
    rows, cols = np.asarray(rows), np.asarray(cols)
    with _PATTERNS_LOCK:
        for i, pat in enumerate(_PATTERNS):
            if pat.matches(rows, cols, n):
                _PATTERNS.insert(0, _PATTERNS.pop(i))
                return pat
        pat = _Pattern(rows, cols, n)
        _PATTERNS.insert(0, pat)
        del _PATTERNS[_MAX_PATTERNS:]
        return pat


def _ldl_solve(pat: _Pattern, vals, rhs):
    """Solve with the pattern's Cholesky factor, or its LDLᵀ when the matrix is not
    positive definite (raises ValueError or RuntimeError when that factorisation fails)."""
    with pat.lock:
        data = pat.upper_data(np.asarray(vals, np.float64))
        out = pat.cholesky_solve(data, rhs)
        return out if out is not None else pat.factor(data).solve(np.asarray(rhs, np.float64))


def _host_solve(pat: _Pattern, vals, rhs):
    """Cholesky, else LDLᵀ with AMD ordering (qdldl), for the symmetric matrix; SuperLU if that fails."""
    n = rhs.shape[0]
    try:
        out = _ldl_solve(pat, vals, rhs)
        if not np.all(np.isfinite(out)):
            raise ValueError("non-finite LDL solution")
    except (ValueError, RuntimeError):
        try:
            lu = spla.splu(_csc(pat.rows, pat.cols, vals, n), permc_spec="MMD_AT_PLUS_A")
            out = lu.solve(np.asarray(rhs, np.float64))
        except RuntimeError:
            out = np.full(n, np.nan)
    return out.astype(rhs.dtype)


SHIFT_FIRST, SHIFT_MIN, SHIFT_MAX = 1e-4, 1e-7, 1e3
"""Diagonal shifts, as multiples of the mean |diagonal entry|. Indefinite Newton matrices met in
drapes needed 1e-5 to 1e3, mostly 1e-4 to 1e-3 (a few soft buckling modes): a first shift
ladder starts at ``SHIFT_FIRST``, a later one a tenth below the previous step's shift (not
under ``SHIFT_MIN``), so that near a saddle the shift falls to the least that works and the
step along its unstable mode grows (a fixed 1e-4 crept along one for hundreds of iterations).
The ladder rises tenfold up to ``SHIFT_MAX``, where the shift dominates the matrix (a damped
gradient step)."""


def _host_solve_shifted(pat: _Pattern, vals, rhs, previous, ladder: bool = True, ceiling: float = SHIFT_MAX):
    """Cholesky solve of A + μ·mean|diag A|·I for the first μ that makes it positive definite: 0,
    then a tenfold ladder from a tenth of ``previous`` (``SHIFT_FIRST`` when it is 0) up to
    ``ceiling`` (at most ``SHIFT_MAX``).

    The factorisation succeeds exactly when the matrix is positive definite, so each one says whether
    its step points at a minimum or at a saddle. Returns the solution and μ (0: the exact matrix was
    positive definite; inf, with a NaN solution: no shift up to ``SHIFT_MAX`` was, or the
    factorisation failed). ``ladder=False``: the exact matrix only.
    """
    n = rhs.shape[0]
    b = np.asarray(rhs, np.float64)
    previous = float(previous)
    first = SHIFT_FIRST if previous <= 0 else min(max(0.1 * previous, SHIFT_MIN), SHIFT_MAX)
    top = min(float(ceiling), SHIFT_MAX)
    first = min(first, top)
    rungs = int(np.log10(top / first) + 1e-9) + 1 if ladder and top > 0 else 0
    shifts = [0.0] + [first * 10.0**k for k in range(rungs)]
    with pat.lock:
        data = pat.upper_data(np.asarray(vals, np.float64))
        scale = np.mean(np.abs(data[pat.diag]))
        for mu in shifts if np.all(np.isfinite(data)) else ():
            shifted = data.copy()
            shifted[pat.diag] += mu * scale
            out = pat.cholesky_solve(shifted, b)
            if out is not None:
                return out.astype(rhs.dtype), np.asarray(mu, rhs.dtype)
    return np.full(n, np.nan, rhs.dtype), np.asarray(np.inf, rhs.dtype)


def _host(kind: str, host_fn, rows, cols, n: int, shapes, *args):
    """``host_fn(pattern, *args)`` on the host, as a cacheable FFI target on CPU
    (``_host_ffi``) and through ``jax.pure_callback`` from other backends.

    When the triplet positions are constants of the trace (``hessian_coo`` of a closed-over
    mesh), the pattern is looked up once, here, and bound to the host function: each call then
    carries only the values. Copying the positions to the host and comparing them with the
    cached patterns on every Newton iteration took a fifth of a 25 mm diagnosis's time.
    Traced positions are carried and looked up per call. ``kind`` names ``host_fn`` and its
    settings: with the pattern's hash it is the target's name in every process.
    """
    try:
        pat = _pattern(np.asarray(rows), np.asarray(cols), n)
        fn, carried, name = functools.partial(host_fn, pat), (), target_name(kind, pat.name)
    except jax.errors.TracerArrayConversionError:
        fn, carried = (lambda r, c, *a: host_fn(_pattern(r, c, n), *a)), (rows, cols)
        name = target_name(kind, "traced", n)
    if jax.default_backend() != "cpu":
        return jax.pure_callback(fn, shapes, *carried, *args, vmap_method="sequential")
    return host_call(name, fn, shapes, *carried, *args, vmap_method="sequential")


def sparse_solve_shifted(rows, cols, vals, rhs, previous=0.0, ladder: bool = True, ceiling: float = SHIFT_MAX):
    """Newton step by the exact matrix or the least shifted positive definite one (see
    ``_host_solve_shifted``; ``previous``: the last step's shift; ``ladder=False``: no shift;
    ``ceiling``: the largest shift tried): (solution, μ), μ = 0 exact, inf none."""
    shapes = (jax.ShapeDtypeStruct(rhs.shape, rhs.dtype), jax.ShapeDtypeStruct((), rhs.dtype))
    fn = functools.partial(_host_solve_shifted, ladder=ladder, ceiling=ceiling)
    return _host(f"shifted_{bool(ladder)}_{float(ceiling)!r}", fn, rows, cols, rhs.shape[0], shapes, vals, rhs,
                 jnp.asarray(previous, rhs.dtype))


def sparse_solve(rows, cols, vals, rhs):
    """Solve A y = rhs for the COO matrix A on the host (works under jit and vmap)."""
    return _host("solve", _host_solve, rows, cols, rhs.shape[0], jax.ShapeDtypeStruct(rhs.shape, rhs.dtype), vals, rhs)
