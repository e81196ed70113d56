"""The consensus-shape fit's energy terms and solver (Sec. B.3.3, Eq. B.7–B.11): the data term
on unposed silhouette rays, the Gauss–Newton step of the shape parameters β and the sparse
least-squares step of the per-vertex offsets D. :mod:`monoavatar.fit.shape` alternates them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch
from torch import Tensor

from monoavatar.body import BodyModel
from monoavatar.fit.energies import geman_mcclure
from monoavatar.fit.rays import CanonicalRays

if TYPE_CHECKING:
    from monoavatar.fit.shape import ShapeSettings


# -- energy terms ---------------------------------------------------------------------------


def line_data_energy(vertices: Tensor, moment: Tensor, direction: Tensor, sigma: float) -> Tensor:
    """The data term of Eq. B.8 (unnormalised): ``Σ_c ρ(|v_c × n_c − m_c|)``.

    Args:
        vertices: (N, 3) each correspondence's vertex; moment, direction: (N, 3) its
            canonical line in Plücker coordinates (unit directions).
        sigma: Geman-McClure scale, metres.
    Returns:
        () scalar, m².
    """
    r = torch.cross(vertices, direction, dim=-1) - moment
    return geman_mcclure((r * r).sum(-1), sigma).sum()


def robust_weights(d2: np.ndarray, sigma: float | np.ndarray) -> np.ndarray:
    """IRLS weights of Geman-McClure, ``dρ/d(r²) = σ⁴ / (σ² + r²)²``."""
    s2 = sigma * sigma
    return np.asarray((s2 / (s2 + d2)) ** 2)


def projectors(rays: CanonicalRays, data_term: str) -> np.ndarray:
    """(N, 3, 3) per-ray projectors P with ``d² = |P (v − p0)|²``."""
    if data_term == "plane":
        p = rays.plane_normal
        return np.einsum("ni,nj->nij", p, p)
    n = rays.direction
    return np.eye(3)[None] - np.einsum("ni,nj->nij", n, n)


def squared_distances(
    vertices: np.ndarray, rays: CanonicalRays, proj: np.ndarray, anchor: np.ndarray
) -> np.ndarray:
    diff = vertices[rays.vertex_ids] - anchor
    return np.einsum("ni,nij,nj->n", diff, proj, diff)


@dataclass
class DataSystem:
    """Per-vertex accumulation of the robustly weighted data term:
    ``A_i = s Σ_c w_c P_c`` (V, 3, 3) and ``c_i = s Σ_c w_c P_c p0_c`` (V, 3)."""

    A: np.ndarray
    c: np.ndarray


def accumulate(
    rays: CanonicalRays,
    proj: np.ndarray,
    anchor: np.ndarray,
    weights: np.ndarray,
    num_vertices: int,
) -> DataSystem:
    wp = weights[:, None, None] * proj
    ids = rays.vertex_ids
    A = np.zeros((num_vertices, 9))
    c = np.zeros((num_vertices, 3))
    flat = wp.reshape(-1, 9)
    for k in range(9):
        A[:, k] = np.bincount(ids, flat[:, k], minlength=num_vertices)
    wpp = np.einsum("nij,nj->ni", wp, anchor)
    for k in range(3):
        c[:, k] = np.bincount(ids, wpp[:, k], minlength=num_vertices)
    return DataSystem(A.reshape(-1, 3, 3), c)


# -- the solver -----------------------------------------------------------------------------


@dataclass
class Problem:
    """Constants of one fit."""

    body: BodyModel
    laplacian: sp.csr_matrix
    sym_x: sp.csr_matrix
    sym_yz: sp.csr_matrix
    tau_lp: np.ndarray  # (V,) region multipliers of E_lp
    tau_var: np.ndarray  # (V,) region multipliers of E_var
    rigidity: sp.csr_matrix  # (V, V) weighted edge Laplacian of the rigidity term
    num_vertices: int


def rest_vertices(body: BodyModel, beta: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        v, _ = body.rest_shape(torch.as_tensor(beta, dtype=body.dtype)[None])
    return np.asarray(v[0].double().numpy())


def rest_jacobian(body: BodyModel, beta: np.ndarray, step: float = 1e-3) -> np.ndarray:
    """(V, 3, S) finite-difference Jacobian of the rest vertices w.r.t. β (central)."""
    S = len(beta)
    batch = np.repeat(beta[None], 2 * S, axis=0)
    for k in range(S):
        batch[2 * k, k] += step
        batch[2 * k + 1, k] -= step
    with torch.no_grad():
        out, _ = body.rest_shape(torch.as_tensor(batch, dtype=body.dtype))
    v = out.double().numpy()
    return np.stack([(v[2 * k] - v[2 * k + 1]) / (2 * step) for k in range(S)], axis=-1)


def data_energy(d2: np.ndarray, sigma: float | np.ndarray, scale: float | np.ndarray) -> float:
    """``Σ_c s_c ρ_σc(d_c)``: the robust data term of squared distances ``d2`` (N,), with a
    Geman-McClure scale and a weight that are scalars or per ray (N,)."""
    s2 = np.asarray(sigma) ** 2
    return float(np.sum(scale * s2 * d2 / (s2 + d2)))


def shape_step(
    problem: Problem,
    beta: np.ndarray,
    beta_init: np.ndarray,
    offsets: np.ndarray,
    rays: CanonicalRays,
    proj: np.ndarray,
    anchor: np.ndarray,
    sigma: float | np.ndarray,
    scale: float | np.ndarray,
    settings: ShapeSettings,
) -> np.ndarray:
    """Levenberg-Marquardt iterations on β with fixed offsets and correspondences."""
    body = problem.body
    lam = settings.shape_prior
    mu = 1e-3

    def energy(b: np.ndarray) -> float:
        d2 = squared_distances(rest_vertices(body, b) + offsets, rays, proj, anchor)
        return data_energy(d2, sigma, scale) + lam * float(np.sum((b - beta_init) ** 2))

    current = energy(beta)
    for _ in range(settings.shape_iterations):
        v = rest_vertices(body, beta) + offsets
        d2 = squared_distances(v, rays, proj, anchor)
        w = scale * robust_weights(d2, sigma)
        data = accumulate(rays, proj, anchor, w, problem.num_vertices)
        used = np.flatnonzero(data.A.reshape(-1, 9).any(axis=1))
        J = rest_jacobian(body, beta)[used]  # (U, 3, S)
        A = data.A[used]
        H = np.einsum("uis,uij,ujt->st", J, A, J)
        g = np.einsum("uis,ui->s", J, np.einsum("uij,uj->ui", A, v[used]) - data.c[used])
        H = H + lam * np.eye(len(beta))
        g = g + lam * (beta - beta_init)
        improved = False
        for _ in range(6):
            step = np.linalg.solve(H + mu * np.diag(np.diag(H)), -g)
            candidate = np.clip(beta + step, -0.5, 0.5)
            e = energy(candidate)
            if e < current:
                beta, current, mu = candidate, e, max(mu * 0.3, 1e-6)
                improved = True
                break
            mu *= 10.0
        if not improved:
            break
    return beta


def regulariser(
    problem: Problem, w_lp: float, w_var: float, w_sym: float
) -> tuple[sp.csr_matrix, sp.csr_matrix, sp.csr_matrix]:
    """Per-coordinate quadratic forms (V, V): (Q_lp + Q_var) shared, Q_sym for x and y/z."""
    L = problem.laplacian
    q_lp = (L.T @ sp.diags(w_lp * problem.tau_lp) @ L).tocsr()
    q_var = sp.diags(w_var * problem.tau_var).tocsr()
    q_sx = (w_sym * (problem.sym_x.T @ problem.sym_x)).tocsr()
    q_syz = (w_sym * (problem.sym_yz.T @ problem.sym_yz)).tocsr()
    return (q_lp + q_var + problem.rigidity).tocsr(), q_sx, q_syz


def data_matrix(A: np.ndarray) -> sp.csr_matrix:
    """The (3V, 3V) block matrix of per-vertex 3×3 blocks, coordinate-major ordering."""
    V = A.shape[0]
    idx = np.arange(V)
    rows, cols, vals = [], [], []
    for a in range(3):
        for b in range(3):
            rows.append(a * V + idx)
            cols.append(b * V + idx)
            vals.append(A[:, a, b])
    return sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * V, 3 * V)
    )


def offset_step(
    problem: Problem,
    rest: np.ndarray,
    offsets: np.ndarray,
    reference: np.ndarray,
    rays: CanonicalRays,
    proj: np.ndarray,
    anchor: np.ndarray,
    sigma: float | np.ndarray,
    scale: float | np.ndarray,
    weights: tuple[float, float, float],
    normals: np.ndarray | None,
    irls_iterations: int,
) -> np.ndarray:
    """IRLS on the offsets: each iteration one sparse solve of the quadratic model."""
    V = problem.num_vertices
    q_shared, q_sx, q_syz = regulariser(problem, *weights)
    reg = sp.block_diag([q_shared + q_sx, q_shared + q_syz, q_shared + q_syz], format="csr")
    ref = reference.T.reshape(-1)
    rhs_reg = sp.block_diag([q_shared] * 3, format="csr") @ ref
    for _ in range(irls_iterations):
        d2 = squared_distances(rest + offsets, rays, proj, anchor)
        w = scale * robust_weights(d2, sigma)
        data = accumulate(rays, proj, anchor, w, V)
        rhs_data = data.c - np.einsum("vij,vj->vi", data.A, rest)
        M = (reg + data_matrix(data.A)).tocsr()
        rhs = rhs_data.T.reshape(-1) + rhs_reg
        if normals is None:
            x = solve_cg(M, rhs, offsets.T.reshape(-1))
            offsets = x.reshape(3, V).T.copy()
        else:
            N = normal_basis(normals)
            s = solve_cg((N.T @ M @ N).tocsr(), N.T @ rhs, np.einsum("vc,vc->v", offsets, normals))
            offsets = s[:, None] * normals
    return offsets


def normal_basis(normals: np.ndarray) -> sp.csr_matrix:
    """(3V, V) map from per-vertex normal offsets to coordinate-major 3D offsets."""
    V = normals.shape[0]
    idx = np.arange(V)
    rows = np.concatenate([idx, V + idx, 2 * V + idx])
    cols = np.concatenate([idx, idx, idx])
    return sp.csr_matrix((normals.T.reshape(-1), (rows, cols)), shape=(3 * V, V))


def solve_cg(M: sp.csr_matrix, rhs: np.ndarray, x0: np.ndarray, rtol: float = 1e-4) -> np.ndarray:
    """Solve the SPD system M x = rhs by Jacobi-preconditioned conjugate gradients from x0
    (the previous offsets: warm-started, CG is much cheaper than a sparse direct solve).

    Stops at relative residual ``rtol`` or after 2000 iterations."""
    diag = M.diagonal()
    inv = np.divide(1.0, diag, out=np.ones_like(diag), where=diag > 0)
    pre = spla.LinearOperator(M.shape, matvec=lambda v: inv * v, dtype=np.float64)
    x, _ = spla.cg(M, rhs, x0=x0, rtol=rtol, maxiter=2000, M=pre)
    return np.asarray(x)
