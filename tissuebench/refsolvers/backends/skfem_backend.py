"""scikit-fem backend.

scikit-fem supplies the meshes, reference elements, quadrature and isoparametric
mappings (shape-function gradients and ``dx`` weights). Element kernels are evaluated
here as batched ``einsum`` over all cells, with the material's analytical tangent
(:mod:`tissuebench.refsolvers.materials`), and scattered into a CSR pattern computed
once: skfem's generic ``asm`` evaluates a form once per pair of local basis functions,
which is too slow for an 81-component tangent on 10^5 cells.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import skfem

from ..materials import Material
from ..mesh import facet_nodes
from ..quadrature import default_order, facet_rule, mass_order, volume_rule
from ..problem import BodyForce, FollowerPressure, SurfaceTraction
from .base import Backend, CellKernel, check_cells, lump_mass, material_on_cells

# skfem's local vertex order of MeshHex1 expressed in VTK hexahedron order
_VTK_TO_SKFEM_HEX = [0, 4, 3, 1, 7, 5, 2, 6]
_FACET_ELEMENTS = {3: skfem.ElementTriP1, 6: skfem.ElementTriP2, 4: skfem.ElementQuad1}


class _Pattern:
    """CSR sparsity of a cell-to-dof map plus the scatter index of every element entry."""

    def __init__(self, cell_dofs, ndof):
        n_loc = cell_dofs.shape[1]
        rows = np.repeat(cell_dofs, n_loc, axis=1).ravel()
        cols = np.tile(cell_dofs, (1, n_loc)).ravel()
        keys, self.scatter = np.unique(rows * ndof + cols, return_inverse=True)
        self.scatter = self.scatter.ravel()
        self.indices = (keys % ndof).astype(np.int32)
        self.indptr = np.searchsorted(keys // ndof, np.arange(ndof + 1)).astype(np.int64)
        self.shape = (ndof, ndof)

    def assemble(self, element_matrices):
        data = np.bincount(self.scatter, weights=element_matrices.ravel(), minlength=len(self.indices))
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


def _total_lagrangian(material):
    """True if ``stress_and_tangent`` is the base class's push-forward of ``pk2``: then the
    element matrices are built from S and dS/dE directly, without the 81-component dP/dF."""
    return type(material).stress_and_tangent is Material.stress_and_tangent


def _tl_element_tangents(F, S, CC, grad, dx):
    """Element tangents from the second Piola-Kirchhoff stress and its tangent.

    ``K_aibk = sum_q dx (delta_ik g_aJ S_JL g_bL + F_iI g_aJ CC_IJKL F_kK g_bL)``: the same
    contraction as ``g A g`` with ``A = dP/dF`` (:func:`~..materials._pk1_tangent`), done as
    B D B^T with B (3 n_loc, 9) so that no (n_cells, n_qp, 3, 3, 3, 3) product is formed.

    Parameters
    ----------
    F, S : ndarray, shape (e, q, 3, 3)
    CC : ndarray, shape (e, q, 3, 3, 3, 3)
    grad : ndarray, shape (e, q, n_loc, 3)
        Reference shape-function gradients.
    dx : ndarray, shape (e, q)

    Returns
    -------
    ndarray, shape (e, 3 n_loc, 3 n_loc)
    """
    e, q, n = grad.shape[:3]
    B = np.einsum("eqiI,eqaJ->eqaiIJ", F, grad).reshape(e * q, 3 * n, 9)
    D = (CC * dx[:, :, None, None, None, None]).reshape(e * q, 9, 9)
    K = np.matmul(np.matmul(B, D), B.transpose(0, 2, 1)).reshape(e, q, 3 * n, 3 * n).sum(axis=1)
    geo = np.einsum("eq,eqaJ,eqJL,eqbL->eab", dx, grad, S, grad, optimize=True)
    K = K.reshape(e, n, 3, n, 3)
    for i in range(3):  # delta_ik: the geometric term on the diagonal of each 3x3 block
        K[:, :, i, :, i] += geo
    return K.reshape(e, 3 * n, 3 * n)


def _pk1_element_tangents(A, grad, dx):
    """Element tangents ``K_aibk = sum_q dx g_aJ A_iJkL g_bL`` from ``A = dP/dF`` (e, q, 3, 3, 3, 3),
    as ``B^T A B`` with ``B`` (3 n_loc, 9) per quadrature point: batched matrix products instead of
    one six-index einsum (which took ~0.1 s for 128 Q1 cells; materials that give dP/dF themselves:
    Guccione's fibre part, the corotational material)."""
    e, q, n = grad.shape[:3]
    # B[(a, i), (i', J)] = delta_ii' g_aJ
    B = np.einsum("eqaJ,ik->eqaikJ", grad, np.eye(3)).reshape(e * q, 3 * n, 9)
    D = (A * dx[:, :, None, None, None, None]).reshape(e * q, 9, 9)
    K = np.matmul(np.matmul(B, D), B.transpose(0, 2, 1))
    return K.reshape(e, q, 3 * n, 3 * n).sum(axis=1)


class _CellKernel:
    """Shape-function values/gradients of one scalar basis, in tissuebench node numbering."""

    def __init__(self, basis, nodes_of_dof, local_order=None):
        # local_order[a] = skfem local index of tissuebench local node a (VTK order)
        order = np.arange(len(basis.basis)) if local_order is None else np.asarray(local_order)
        self.nodes = nodes_of_dof[basis.element_dofs].T[:, order]  # (n_cells, n_loc)
        self.grad = np.stack([basis.basis[a][0].grad for a in order])  # (a, J, e, q)
        self.grad = np.ascontiguousarray(self.grad.transpose(2, 3, 0, 1))  # (e, q, a, J)
        self.value = np.stack([np.asarray(basis.basis[a][0]) for a in order])  # (a, e, q)
        self.value = np.ascontiguousarray(self.value.transpose(1, 2, 0))  # (e, q, a)
        self.dx = np.asarray(basis.dx)  # (e, q) = |det J| * weight
        self.dofs = (3 * self.nodes[:, :, None] + np.arange(3)).reshape(len(self.nodes), -1)

    def deformation_gradient(self, u):
        U = u.reshape(-1, 3)[self.nodes]  # (e, a, i)
        return np.eye(3) + np.einsum("eai,eqaJ->eqiJ", U, self.grad, optimize=True)


class SkfemCellKernel(CellKernel):
    """Element operators of a subset of cells (batched einsum over the subset only).

    Holds the shape-function gradients and quadrature weights of the selected cells and
    the material restricted to them; a call costs O(len(cells)).
    """

    def __init__(self, kernel: _CellKernel, material, cells):
        self.cells = cells
        self.grad = np.ascontiguousarray(kernel.grad[cells])  # (m, q, a, J)
        self.dx = np.ascontiguousarray(kernel.dx[cells])  # (m, q)
        self.dofs = kernel.dofs[cells]
        self.volumes = self.dx.sum(axis=1)
        self.material = material_on_cells(material, cells)
        self._G = self.grad * self.dx[:, :, None, None]

    def deformation_gradient(self, u_loc):
        """F at the quadrature points, shape (m, q, 3, 3)."""
        U = self._check_local(u_loc).reshape(len(self.cells), -1, 3)
        return np.eye(3) + np.einsum("eai,eqaJ->eqiJ", U, self.grad, optimize=True)

    def energies_and_forces(self, u_loc):
        F = self.deformation_gradient(u_loc)
        W, P = self.material.energy_and_stress(F)
        fe = np.einsum("eqiJ,eqaJ->eai", P, self._G, optimize=True)
        return np.einsum("eq,eq->e", self.dx, W), fe.reshape(len(fe), -1)

    def forces_and_tangents(self, u_loc):
        F = self.deformation_gradient(u_loc)
        P, A = self.material.stress_and_tangent(F)
        Ke = _pk1_element_tangents(A, self.grad, self.dx)
        fe = np.einsum("eqiJ,eqaJ->eai", P, self._G, optimize=True)
        return fe.reshape(len(fe), -1), Ke


class SkfemBackend(Backend):
    """Operators assembled with scikit-fem bases (P1/P2 tetrahedra, Q1 hexahedra)."""

    name = "skfem"

    def __init__(self, problem):
        super().__init__(problem)
        mesh, element = problem.mesh, problem.element
        if element == "Q1":
            self._skmesh = skfem.MeshHex(mesh.points.T.copy(), mesh.cells[:, _VTK_TO_SKFEM_HEX].T.copy())
            self._elem = skfem.ElementHex1()
        else:
            self._skmesh = skfem.MeshTet(mesh.points.T.copy(), mesh.cells.T.copy())
            self._elem = skfem.ElementTetP2() if element == "P2" else skfem.ElementTetP1()
        order = problem.quadrature_order or default_order(element)
        basis = skfem.Basis(self._skmesh, self._elem, quadrature=volume_rule(element, order))
        self._nodes_of_dof = self._node_map(basis)
        self._local_order = np.argsort(_VTK_TO_SKFEM_HEX) if element == "Q1" else None
        self._k = _CellKernel(basis, self._nodes_of_dof, self._local_order)
        # element quantities are reported in the node order of problem.layout[1]
        assert np.array_equal(self._k.nodes, problem.layout[1])
        self._pattern = None
        self._order = order

    # ------------------------------------------------------------------ numbering
    def _node_map(self, basis):
        """tissuebench node index of every skfem scalar dof."""
        nmap = np.empty(basis.N, dtype=np.int64)
        nmap[basis.nodal_dofs[0]] = np.arange(self.problem.mesh.n_vertices)
        if self.problem.element == "P2":
            nv = self.problem.mesh.n_vertices
            sk_edges = np.sort(self._skmesh.edges.T, axis=1)
            ours = self.problem.mesh.edges
            ids = np.searchsorted(ours[:, 0] * nv + ours[:, 1], sk_edges[:, 0] * nv + sk_edges[:, 1])
            nmap[basis.edge_dofs[0]] = nv + ids
        return nmap

    @property
    def pattern(self):
        if self._pattern is None:
            self._pattern = _Pattern(self._k.dofs, self.ndof)
        return self._pattern

    def _scatter_vector(self, element_vectors, dofs=None):
        dofs = self._k.dofs if dofs is None else dofs
        return np.bincount(dofs.ravel(), weights=element_vectors.ravel(), minlength=self.ndof)

    # ------------------------------------------------------------------ internal forces
    def _element_forces(self, u):
        F = self._k.deformation_gradient(self._check_u(u))
        P = self.problem.material.stress(F)
        fe = np.einsum("eq,eqiJ,eqaJ->eai", self._k.dx, P, self._k.grad, optimize=True)
        return fe.reshape(len(fe), -1)

    def internal_force(self, u):
        return self._scatter_vector(self._element_forces(u))

    def _element_tangents(self, u):
        F = self._k.deformation_gradient(self._check_u(u))
        G = self._k.grad * self._k.dx[:, :, None, None]
        mat = self.problem.material
        if _total_lagrangian(mat):
            S, CC = mat.pk2(F, tangent=True)
            P, Ke = F @ S, _tl_element_tangents(F, S, CC, self._k.grad, self._k.dx)
        else:  # the material gives dP/dF itself
            P, A = mat.stress_and_tangent(F)
            Ke = _pk1_element_tangents(A, self._k.grad, self._k.dx)
        fe = np.einsum("eqiJ,eqaJ->eai", P, G, optimize=True)
        return fe.reshape(len(fe), -1), Ke

    def tangent(self, u):
        return self.pattern.assemble(self._element_tangents(u)[1])

    def internal_force_and_tangent(self, u):
        fe, Ke = self._element_tangents(u)
        return self._scatter_vector(fe), self.pattern.assemble(Ke)

    def element_internal_forces(self, u):
        return self._element_forces(u)

    def cell_kernel(self, cells=None):
        return SkfemCellKernel(self._k, self.problem.material, check_cells(cells, self.problem.mesh.n_cells))

    # ------------------------------------------------------------------ energies
    def element_strain_energies(self, u):
        F = self._k.deformation_gradient(self._check_u(u))
        return np.einsum("eq,eq->e", self._k.dx, self.problem.material.energy(F))

    def strain_energy(self, u):
        return float(self.element_strain_energies(u).sum())

    def min_jacobian(self, u):
        return float(np.linalg.det(self._k.deformation_gradient(self._check_u(u))).min())

    # ------------------------------------------------------------------ mass
    def mass(self, lumped=False):
        basis = skfem.Basis(self._skmesh, self._elem,
                            quadrature=volume_rule(self.problem.element, mass_order(self.problem.element)))
        k = _CellKernel(basis, self._nodes_of_dof, self._local_order)
        Me = self.problem.density * np.einsum("eq,eqa,eqb->eab", k.dx, k.value, k.value)
        Me = np.einsum("eab,ik->eaibk", Me, np.eye(3)).reshape(len(Me), k.dofs.shape[1], -1)
        M = self.pattern.assemble(Me)
        return lump_mass(M, self.problem.element) if lumped else M

    # ------------------------------------------------------------------ loads
    def _volume_load(self):
        f = np.zeros(self.ndof)
        for ld in self.problem.loads:
            if isinstance(ld, BodyForce):
                fe = np.einsum("eq,eqa,i->eai", self._k.dx, self._k.value, np.asarray(ld.force, float))
                f += self._scatter_vector(fe.reshape(len(fe), -1))
        return f

    def _facet_kernel(self, facets):
        """(node indices (f, n_loc), N (q, n_loc), dN (q, n_loc, 2), weights (q,))."""
        facets = facet_nodes(self.problem.mesh, facets, self.problem.element)
        elem = _FACET_ELEMENTS[facets.shape[1]]()
        X, W = facet_rule(self.problem.element, self._order)
        N = np.stack([elem.lbasis(X, a)[0] for a in range(facets.shape[1])], axis=-1)
        dN = np.stack([elem.lbasis(X, a)[1] for a in range(facets.shape[1])], axis=1)  # (2, a, q)
        return facets, N, np.transpose(dN, (2, 1, 0)), W

    def _facet_tangents(self, x_facet, dN):
        """Surface tangents x_,1 and x_,2 at quadrature points, shape (f, q, 3) each."""
        t = np.einsum("fai,qad->fqdi", x_facet, dN)
        return t[:, :, 0], t[:, :, 1]

    def _surface_loads(self, u, load_factor, with_tangent):
        x = self.problem.nodes + u.reshape(-1, 3)
        f = np.zeros(self.ndof)
        rows, cols, vals = [], [], []
        for ld in self.problem.loads:
            if not isinstance(ld, (SurfaceTraction, FollowerPressure)):
                continue
            nodes, N, dN, W = self._facet_kernel(self.problem.facets_of(ld))
            dofs = (3 * nodes[:, :, None] + np.arange(3)).reshape(len(nodes), -1)
            if isinstance(ld, SurfaceTraction):
                t1, t2 = self._facet_tangents(self.problem.nodes[nodes], dN)
                dA = np.linalg.norm(np.cross(t1, t2), axis=-1) * W  # (f, q)
                fe = load_factor * np.einsum("fq,qa,i->fai", dA, N, np.asarray(ld.traction, float))
            else:
                p = load_factor * float(ld.pressure)
                t1, t2 = self._facet_tangents(x[nodes], dN)
                fe = -p * np.einsum("q,qa,fqi->fai", W, N, np.cross(t1, t2))
                if with_tangent:
                    ke = self._pressure_tangent(p, N, dN, W, t1, t2)
                    n = ke.shape[1]
                    rows.append(np.repeat(dofs, n, axis=1).ravel())
                    cols.append(np.tile(dofs, (1, n)).ravel())
                    vals.append(ke.ravel())
            f += self._scatter_vector(fe.reshape(len(fe), -1), dofs)
        K = None
        if rows:
            K = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                              shape=(self.ndof, self.ndof))
        return f, K

    @staticmethod
    def _pressure_tangent(p, N, dN, W, t1, t2):
        """d/du_b of -p int N_a (x_,1 x x_,2): (f, 3 n_loc, 3 n_loc)."""
        eps = np.zeros((3, 3, 3))
        eps[0, 1, 2] = eps[1, 2, 0] = eps[2, 0, 1] = 1.0
        eps[0, 2, 1] = eps[2, 1, 0] = eps[1, 0, 2] = -1.0
        # d(t1 x t2)_i / du_bk = eps_ijl (dN_b1 delta_jk t2_l + t1_j dN_b2 delta_lk)
        d = (np.einsum("ikl,qb,fql->fqibk", eps, dN[:, :, 0], t2)
             + np.einsum("ijk,fqj,qb->fqibk", eps, t1, dN[:, :, 1]))
        ke = -p * np.einsum("q,qa,fqibk->faibk", W, N, d)
        n = ke.shape[1] * 3
        return ke.reshape(len(ke), n, n)

    def external_force(self, u, load_factor):
        u = self._check_u(u)
        f = load_factor * (self.problem.point_load_vector() + self._volume_load())
        return f + self._surface_loads(u, load_factor, with_tangent=False)[0]

    def external_tangent(self, u, load_factor):
        if not any(isinstance(ld, FollowerPressure) for ld in self.problem.loads):
            return None
        return self._surface_loads(self._check_u(u), load_factor, with_tangent=True)[1]
