"""The field's model-reduction libraries as tissuebench methods: each adapter hands a library the
training tissuebench builds and runs that library's own algorithms, through the public method
contract only (:mod:`tissuebench.rom`), so that it is swept, timed and reported exactly as the
shipped methods, beside the shipped method of the same family (its ``counterpart``).

* ``pymor_galerkin`` (:mod:`.pymor_galerkin`): pyMOR's POD, the finite-element internal force as a
  pyMOR ``Operator``, its empirical interpolation (``deim``, ``EmpiricalInterpolatedOperator``) and
  projection; pyMOR's Newton on static paths, its implicit Euler on trajectories.
* ``romtools_ecsw`` (:mod:`.romtools_ecsw`): Pressio's romtools' POD vector space and ECSW element
  selection (its NNLS), on the same basis, states and integrator as ``pod_galerkin hyper = "ecsw"``.
* ``opinf`` (:mod:`.opinf_model`): OpInf's learned, fully discrete reduced model of the trajectories,
  its operators and regularisation chosen by OpInf.
* ``ezyrb`` (:mod:`.ezyrb_interp`): EZyRB's POD with RBF or GPR interpolation of the coefficients
  (optional: EZyRB pulls torch).

Each library is imported when a method is built, never when tissuebench reads the registry: a
``tissuebench`` command does not pay pyMOR's import, and a library that is not installed makes its
method say so (``tissuebench methods``: "does not apply: needs ...") instead of failing the plugin.
"""
__version__ = "0.1.0"
