"""What a method of another package may ask of a :class:`~.base.Training` besides its snapshots:
the internal force and tangent of a set of elements (:func:`element_kernel`), and ``pod_galerkin``'s
online model on a basis and an element rule of its own (:func:`galerkin_model`). Both are public
(``from tissuebench.rom import element_kernel, galerkin_model``).

The adapters of the field's libraries (``peers/``: pyMOR's empirical interpolation restricts the
internal force to the elements around its interpolation dofs; Pressio's romtools selects ECSW
elements and weights) need both, and a user's hyper-reduction needs the same: the shipped
``pod_galerkin`` builds on the same pieces (:mod:`.galerkin`), so a rule from another library is
measured with the same basis, integrator and Newton iteration as ours, only its rule differing.
They are functions of a training, not methods of it: :mod:`.base` sits below every method family
(:mod:`.galerkin` imports it), so it names none of them.
"""
from __future__ import annotations

import numpy as np

from ..refsolvers.backends.base import CellKernel, check_cells
from .fe_baselines.stepping import ScaledHistory
from .galerkin.forces import LinearForces, element_forces
from .galerkin.kernel import ElementKernel, cell_geometry
from .galerkin.method import PodGalerkin
from .galerkin.model import GalerkinModel
from .galerkin.system import reduced_system
from .training_scene import scene_of

__all__ = ["ElementOperators", "element_kernel", "galerkin_model"]


class ElementOperators(CellKernel):
    """A :class:`~tissuebench.refsolvers.backends.base.CellKernel` of a set of cells computed by
    the Voigt-form kernel of the Galerkin models (:class:`~.galerkin.kernel.ElementKernel`: about
    5x faster than a backend's own cell kernel for the tangents, the same values to round-off).

    Attributes
    ----------
    cells : (m,) int array
        Mesh cell indices.
    dofs : (m, n_loc) int array
        Global dofs of each cell's local dofs (node-major, xyz: ``Backend.element_dofs``).
    volumes : (m,) array
        Reference volumes of the cells.
    """

    def __init__(self, backend, cells):
        self.cells = check_cells(cells, backend.problem.mesh.n_cells)
        grad, dx = cell_geometry(backend, self.cells)
        self._kernel = ElementKernel(grad, dx, backend.problem.material, self.cells)
        self.dofs = backend.element_dofs()[self.cells]
        self.volumes = dx.sum(axis=1)

    def energies_and_forces(self, u_loc):
        """Strain energies (m,) and internal force vectors (m, n_loc) from local displacements (m, n_loc)."""
        return self._kernel.energies_and_forces(self._check_local(u_loc))

    def forces_and_tangents(self, u_loc):
        """Internal force vectors (m, n_loc) and tangents ``d f_e / d u_e`` (m, n_loc, n_loc)."""
        return self._kernel.forces_and_tangents(self._check_local(u_loc))


def _needs(training, who: str, *fields) -> None:
    missing = [f for f in fields if getattr(training, f) is None]
    if missing:
        raise ValueError(f"{who}: the training has no {', '.join(missing)} (needs a finite-element training"
                         f"{' of trajectories' if 'dt' in fields else ''})")


def element_kernel(training, cells=None) -> CellKernel:
    """The internal force and tangent of a set of elements of a training's mesh.

    Parameters
    ----------
    training : Training
        A finite-element training (its ``backend``).
    cells : (m,) int array, optional
        Mesh cell indices (all cells when None; duplicates allowed, order kept).

    Returns
    -------
    CellKernel
        A :class:`~tissuebench.refsolvers.backends.base.CellKernel`: ``dofs`` (m, n_loc) the global dofs
        of each element's local dofs (node-major, xyz), ``gather(u)`` the local displacements (m, n_loc)
        of a full vector (n_dof,), ``energies_and_forces(u_loc)`` (energies (m,), forces (m, n_loc)) and
        ``forces_and_tangents(u_loc)`` (forces (m, n_loc), tangents (m, n_loc, n_loc)) of the backend's
        material and quadrature, their sums over every cell ``backend.internal_force``,
        ``backend.tangent`` and ``backend.strain_energy``: what an empirical interpolation restricts its
        operator to, and what an element-sampling rule (ECSW, cubature) is fitted on. The Voigt-form
        kernel of the Galerkin models (:class:`ElementOperators`); on a linear material the backend's own.

    Raises
    ------
    ValueError
        The training has no finite-element backend, the backend's formulation has no element
        quantities (the average nodal pressure tetrahedra), or a cell index is out of range.
    """
    who = "element_kernel"
    _needs(training, who, "backend")
    be = training.backend
    if getattr(be.problem, "mesh", None) is None:
        raise ValueError(f"{who}: the training's model has no finite-element mesh")
    cells = check_cells(cells, be.problem.mesh.n_cells)
    # the Voigt kernel reads a stress law at the Gauss points: linear elasticity has its matrix, and the
    # mean-dilatation hexahedra a correction per cell besides (issue 54): the backend's own kernel
    own_kernel = be.problem.material.is_linear or getattr(be, "formulation", "") == "mean_dilatation"
    try:  # a formulation whose energy does not split into cells (average nodal pressure) has no element quantities
        own = be.cell_kernel(cells if own_kernel else cells[:1])
    except NotImplementedError as exc:
        raise ValueError(f"{who}: the {type(be).__name__} formulation has no element quantities ({exc})") from None
    return own if own_kernel else ElementOperators(be, cells)


def galerkin_model(training, basis, cells=None, weights=None, *, name: str = "galerkin", integrator=None,
                   rtol: float = 1e-6, max_iterations: int = 20, newton_tangent: str = "reuse",
                   newton_iterations: int | None = None, info=None):
    """A POD-Galerkin trajectory model on ``basis`` with the internal force of weighted ``cells``.

    The online model of ``pod_galerkin`` (the scene's implicit integrator on the Galerkin projection
    ``V^T M V q'' + V^T C V q' + sum_e w_e V_e^T f_e(V_e q) = V^T f_ext(t)``, Newton with the reduced
    tangent; prescribed motion and outputs included) built on another method's basis and element rule,
    so a hyper-reduction of another library is measured with our integrator and only its rule differs.

    Parameters
    ----------
    training : Training
        A trajectory training (snapshots, backend, system, dt).
    basis : (n_free, r) array
        Reduced basis of the free dofs (``training.system.free``; ``u_free = basis @ q``).
    cells, weights : (m,) arrays, optional
        Mesh cells and their non-negative weights (an ECSW rule); default every cell with weight 1
        (full assembly). On a linear material the exact, constant reduced operator whatever the rule
        (as ``pod_galerkin``; ``info["rule_note"]`` says so).
    name : str
        The model's name (its messages say it).
    integrator, rtol, max_iterations, newton_tangent, newton_iterations
        As ``pod_galerkin``'s options (``integrator`` None: the scene's, HHT where it is explicit).
    info : dict, optional
        Entries added to the model's ``info`` (the offline record a sweep stores).

    Returns
    -------
    OnlineModel
        Of kind ``"trajectory"``, with :class:`~.base.LinearReconstruction` and the training's outputs attached.

    Raises
    ------
    ValueError
        Not a trajectory training, a basis of the wrong shape, weights not one per cell or negative,
        follower loads, or an option out of range (each named).
    """
    who = "galerkin_model"
    _needs(training, who, "snapshots", "backend", "system", "dt")
    be, full = training.backend, training.system
    free, fixed = np.asarray(full.free), np.asarray(full.fixed)
    V = np.ascontiguousarray(np.asarray(basis, dtype=float))
    if V.ndim != 2 or V.shape[0] != len(free) or V.shape[1] < 1 or not np.all(np.isfinite(V)):
        raise ValueError(f"{who}: basis must be a finite (n_free, r) array with n_free = {len(free)} rows (the "
                         f"system's free dofs) and r >= 1 columns, got shape {V.shape}")
    n_cells = be.problem.mesh.n_cells
    cells = np.arange(n_cells) if cells is None else check_cells(cells, n_cells)
    w = np.ones(len(cells)) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != cells.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"{who}: weights must be finite, >= 0 and one per cell ({len(cells)}), got shape {w.shape}"
                         + (f", min {w.min():.3g}" if w.size and np.all(np.isfinite(w)) else ""))
    basis_full = np.zeros((full.n, V.shape[1]))
    basis_full[free] = V
    linear = bool(be.problem.material.is_linear)
    note = {}
    if linear:  # as pod_galerkin: a linear law's reduced operator is exact and constant, no rule samples it
        K = be.tangent(np.zeros(full.n))
        K_rc = V.T @ K[free][:, fixed].toarray() if full.has_prescribed else None
        forces = LinearForces(V.T @ (K[free][:, free] @ V), K_rc)
        if weights is not None or len(cells) != n_cells:
            note = {"rule_note": f"linear material: the exact reduced operator, not the {len(cells)} weighted cells"}
    else:
        forces = element_forces(be, cells, w, basis_full, fixed)
    history = training.history if training.history is not None else getattr(scene_of(training, who), "history", None)
    if history is None:
        raise ValueError(f"{who}: the training has no load history")
    driven = ScaledHistory(history)
    system = reduced_system(full, V, free, forces, be, driven, linear=linear)
    try:  # the options of pod_galerkin's Newton iteration, checked by it
        stepping = PodGalerkin(rtol=rtol, max_iterations=max_iterations, newton_tangent=newton_tangent,
                               newton_iterations=newton_iterations, integrator=integrator)
    except ValueError as exc:
        raise ValueError(f"{who}: {str(exc).replace('pod_galerkin option ', '')}") from None
    options = stepping._integrator(training)
    lam = training.parameter_values("load_factor") if training.parameters else np.zeros(0)
    envelope = {"load_factor": (float(lam.min()), float(lam.max()))} if lam.size else {}
    record = {"n_modes": int(V.shape[1]), "elements_per_evaluation": int(getattr(forces, "size", 0)),
              "integrator": options[0], "integrator_options": options[1], "linear_material": linear, **note,
              **(info or {})}
    model = GalerkinModel(V, free, be, system, options, driven, np.linalg.pinv(V), envelope, record)
    model.name = name
    if training.outputs:
        model.attach_outputs(training.outputs)
    return model
